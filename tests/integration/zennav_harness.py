"""Integration harness (helpers imported by the tests; fixtures in conftest.py): real service processes over real
Zenoh on loopback.

Each test gets a rendezvous: the test's own zenoh peer session listening on a free loopback port with
multicast scouting off; every service process connects to it (explicit endpoint) and finds the others by
gossip. Nothing is synchronised by sleeping: tests wait on liveliness or on messages, with timeouts.
Every process started here is stopped (SIGTERM, then SIGKILL) at teardown, and its log is printed on failure.
"""
from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

PY = sys.executable


def json_lines(proc) -> list[dict]:
    """The JSON objects a process printed one per line so far (e.g. `zennav monitor --json`)."""
    out = []
    for line in proc.text().splitlines():
        line = line.strip()
        if line.startswith("{"):
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:
                pass
    return out


_KEYS: dict[str, Path] = {}


def dev_keys() -> tuple[Path, Path]:
    """This test process's parameter-set signing key pair (private, public), made once (zennav.learn.signing)."""
    if not _KEYS:
        import tempfile

        from zennav.learn.signing import generate

        _KEYS["private"], _KEYS["public"] = generate(tempfile.mkdtemp(prefix="zennav-keys-"))
    return _KEYS["private"], _KEYS["public"]


def sign(msg: dict) -> dict:
    """A model_params message signed with dev_keys() (the key every service of a Cluster trusts)."""
    from zennav.learn.signing import Signer

    return {**msg, "signature": Signer.from_file(dev_keys()[0]).sign(msg["checksum"])}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_until(pred, timeout: float, what: str = "condition", poll=None):
    """Wait for pred() to become truthy; pred is re-evaluated whenever ``poll`` (an Event) fires or every
    50 ms. Fails the test with ``what`` on timeout."""
    deadline = time.monotonic() + timeout
    while True:
        v = pred()
        if v:
            return v
        if time.monotonic() > deadline:
            pytest.fail(f"timeout after {timeout:.0f} s waiting for {what}")
        if poll is not None:
            poll.wait(0.05)
            poll.clear()
        else:
            time.sleep(0.05)


class Proc:
    def __init__(self, name: str, argv: list, log: Path, env: dict):
        self.name = name
        self.log = log
        self._f = open(log, "wb")
        self.p = subprocess.Popen(argv, stdout=self._f, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=env,
                                  start_new_session=True)

    @property
    def pid(self) -> int:
        return self.p.pid

    def alive(self) -> bool:
        return self.p.poll() is None

    def stop(self, timeout: float = 10.0) -> int:
        if self.p.poll() is None:
            try:
                self.p.send_signal(signal.SIGTERM)
                self.p.wait(timeout)
            except subprocess.TimeoutExpired:
                self.p.kill()
                self.p.wait(5)
        self._f.close()
        return self.p.returncode

    def kill(self) -> None:
        self.p.kill()
        self.p.wait(5)

    def wait(self, timeout: float) -> int:
        return self.p.wait(timeout)

    def text(self) -> str:
        if not self._f.closed:
            self._f.flush()
        return self.log.read_text(errors="replace")


class Cluster:
    """The test's rendezvous session plus the processes it starts."""

    def __init__(self, tmp: Path, vehicle: str = "car"):
        from zennav.bus import Bus

        self.tmp = tmp
        self.vehicle = vehicle
        self.port = free_port()
        self.endpoint = f"tcp/127.0.0.1:{self.port}"
        self.bus = Bus("tester", vehicle, mode="peer", listen=[self.endpoint], connect=[], token=True)
        self.keys = self.bus.keys
        self.procs: list[Proc] = []
        self.env = dict(os.environ, PYTHONUNBUFFERED="1", ZENNAV_LOG="INFO")
        for k in ("ZENNAV_CONNECT", "ZENNAV_LISTEN", "ZENNAV_MODE", "ZENNAV_ZENOH_CONFIG"):
            self.env.pop(k, None)
        # trainers sign with the test process's key, predictors trust it; versions persist per test
        private, public = dev_keys()
        self.env.update(ZENNAV_SIGNING_KEY=str(private), ZENNAV_VERIFY_KEY=str(public), ZENNAV_KEYS=str(public.parent),
                        ZENNAV_STATE_DIR=str(tmp / "state"))

    def bus_args(self) -> list:
        return ["--connect", self.endpoint, "--vehicle", self.vehicle]

    def start(self, name: str, module: str, *args, bus_args: bool = True) -> Proc:
        """Start ``python -m module args`` (plus the bus arguments); module may also be a script path."""
        head = [PY, module] if module.endswith(".py") else [PY, "-m", module]
        argv = [*head, *map(str, args), *(self.bus_args() if bus_args else [])]
        n = sum(1 for p in self.procs if p.name.startswith(name))
        proc = Proc(name, argv, self.tmp / f"{name}-{n}.log", self.env)
        self.procs.append(proc)
        return proc

    def service(self, name: str, *args, wait: bool = True, timeout: float = 30.0) -> Proc:
        """Start zennav.services.<name> and (by default) wait until its liveliness token is up."""
        proc = self.start(name, f"zennav.services.{name}", *args)
        if wait:
            self.wait_alive([name], timeout, proc)
        return proc

    def zennav(self, name: str, *args, bus_args: bool = False) -> Proc:
        """Start the `zennav` console command (e.g. router, launch, record, bus-replay)."""
        exe = str(Path(PY).parent / "zennav")
        argv = [exe, *map(str, args), *(self.bus_args() if bus_args else [])]
        n = sum(1 for p in self.procs if p.name.startswith(name))
        proc = Proc(name, argv, self.tmp / f"{name}-{n}.log", self.env)
        self.procs.append(proc)
        return proc

    def wait_alive(self, names, timeout: float = 30.0, proc: Proc | None = None, alive: bool = True) -> None:
        if not self.bus.wait_alive(names, timeout, alive=alive):
            logs = "\n".join(f"--- {p.name}\n{p.text()[-3000:]}" for p in ([proc] if proc else self.procs))
            pytest.fail(f"{names} not {'alive' if alive else 'gone'} after {timeout} s (alive: "
                        f"{sorted(self.bus.alive())})\n{logs}")

    def close(self, failed: bool) -> None:
        for p in reversed(self.procs):
            p.stop()
        if failed:
            for p in self.procs:
                sys.stderr.write(f"\n===== log of {p.name} ({p.log}) =====\n{p.text()[-6000:]}\n")
        self.bus.close()


class Collector:
    """Collects validated messages of one key expression (fifo: lossless) in the test process."""

    def __init__(self, bus, keyexpr: str, capacity: int = 200_000, channel: str = "fifo"):
        self.items: list[tuple[str, dict, int]] = []
        self.event = threading.Event()
        self.lock = threading.Lock()
        bus.subscribe(keyexpr, self._on, channel=channel, capacity=capacity, name="collector")

    def _on(self, key, msg, recv_ns):
        with self.lock:
            self.items.append((key, msg, recv_ns))
        self.event.set()

    def msgs(self, schema: str | None = None) -> list[dict]:
        with self.lock:
            return [m for _, m, _ in self.items if schema is None or m["schema"] == schema]

    def wait(self, pred, timeout: float, what: str):
        return wait_until(lambda: pred(self), timeout, what, self.event)
