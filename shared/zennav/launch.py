"""`zennav launch deploy/<set>.yaml`: start a process set, wait on liveliness until all are up, prefix every
log line with the service name, report services that die and restart them per policy, stop everything
cleanly on Ctrl-C / SIGTERM.

Launch file (YAML)::

    name: local                      # shown in the log
    vehicle: car                     # ZENNAV_VEHICLE of every service
    rendezvous: tcp/127.0.0.1:7447   # the endpoint services connect to ({rendezvous} in commands); a set that
                                     # runs on another host than its router leaves it out: --rendezvous then
    mode: peer                       # ZENNAV_MODE of the services (peer | client: e.g. deploy/trainer.yaml)
    up_timeout_s: 60                 # how long to wait for everything to be alive
    stop_timeout_s: 10               # SIGTERM, then SIGKILL after this
    keys: keys                       # {keys}: the parameter-set key directory (`zennav keys DIR`; ZENNAV_KEYS wins)
    state: state                     # {state}: the services' state directory (ZENNAV_STATE_DIR wins)
    services:
      - name: router                 # the liveliness name awaited (default: name)
        command: [zennav, router, --listen, "{rendezvous}"]
        env: {ZENNAV_MODE: router}   # extra environment
        restart: on-failure          # no | on-failure | always
        max_restarts: 5
        after: []                    # start once these are alive
        optional: false              # true: not awaited (e.g. runs elsewhere)
        exit_ok: false               # true: exiting with 0 is expected (ingest at the end of a stream)
        identity: router             # whose credentials it uses in the secure variant (default: name)

Commands: "zennav..." executables are taken from this interpreter's bin directory; "{python}" is this
interpreter; "{rendezvous}", "{vehicle}", "{keys}" and "{state}" are substituted (relative paths: from the
directory the launcher runs in). Every service gets ZENNAV_CONNECT={rendezvous},
ZENNAV_VEHICLE and ZENNAV_MODE in its environment (explicit --connect/--listen in a command win).

Services die with their launcher, even one killed with SIGKILL: each runs in its own session (a Ctrl-C in the
terminal reaches the launcher only, which stops them in order) with the parent-death signal set to SIGTERM
(zennav.pdeath, Linux), so no service is left running unsupervised.

Secure variant (``zennav launch SET --secure DIR``, credentials of ``zennav certs DIR``): the rendezvous's
scheme becomes tls/, every service a client of the router (mode client), and each gets ZENNAV_SECURE_DIR=DIR and
ZENNAV_IDENTITY=<its identity> (zennav.bus then opens deploy/secure/*.json5 with that identity's credentials).
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import yaml

from . import pdeath
from .stopsignals import on_stop_signals

POLICIES = ("no", "on-failure", "always")


@dataclass
class ServiceSpec:
    name: str
    command: list
    alive_name: str
    env: dict = field(default_factory=dict)
    restart: str = "no"
    max_restarts: int = 5
    after: list = field(default_factory=list)
    optional: bool = False
    exit_ok: bool = False
    identity: str = ""


@dataclass
class LaunchSpec:
    name: str
    vehicle: str
    rendezvous: str
    mode: str
    up_timeout_s: float
    stop_timeout_s: float
    services: list
    keys: str = "keys"
    state: str = "state"
    secure_dir: str | None = None


def load_launch(path, overrides: dict | None = None) -> LaunchSpec:
    try:
        data = yaml.safe_load(Path(path).read_text())
    except yaml.YAMLError as e:
        raise ValueError(f"{path}: not YAML: {' '.join(str(e).split())}") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: not a launch file (a YAML map with rendezvous and services)")
    data.update({k: v for k, v in (overrides or {}).items() if v is not None})
    if not data.get("rendezvous"):
        raise ValueError(f"{path}: no rendezvous: give the router's endpoint, e.g. --rendezvous tcp/<router-ip>:7447")
    if str(data.get("mode", "peer")) not in ("peer", "client"):
        raise ValueError(f"{path}: mode must be peer or client")
    services = []
    for s in data.get("services", []):
        restart = str(s.get("restart", "no")).lower()
        if restart in ("false", "none"):
            restart = "no"
        if restart not in POLICIES:
            raise ValueError(f"{s.get('name')}: restart must be one of {POLICIES}")
        cmd = s["command"]
        if isinstance(cmd, str):
            cmd = cmd.split()
        services.append(ServiceSpec(name=s["name"], command=[str(c) for c in cmd],
                                    alive_name=s.get("liveliness", s["name"]), env=dict(s.get("env", {})),
                                    restart=restart, max_restarts=int(s.get("max_restarts", 5)),
                                    after=list(s.get("after", [])), optional=bool(s.get("optional", False)),
                                    exit_ok=bool(s.get("exit_ok", False)),
                                    identity=str(s.get("identity", s["name"]))))
    names = [s.name for s in services]
    if len(set(names)) != len(names):
        raise ValueError("service names must be unique")
    return LaunchSpec(name=str(data.get("name", Path(path).stem)), vehicle=str(data.get("vehicle", "car")),
                      rendezvous=str(data["rendezvous"]),
                      mode=str(data.get("mode", "peer")), up_timeout_s=float(data.get("up_timeout_s", 60)),
                      stop_timeout_s=float(data.get("stop_timeout_s", 10)), services=services,
                      keys=os.environ.get("ZENNAV_KEYS") or str(data.get("keys", "keys")),
                      state=os.environ.get("ZENNAV_STATE_DIR") or str(data.get("state", "state")))


def secure_variant(spec: LaunchSpec, secure_dir: str | os.PathLike) -> LaunchSpec:
    """The set's secure variant (module docstring): tls/ rendezvous, clients only, credentials in secure_dir."""
    scheme, _, address = spec.rendezvous.partition("/")
    if scheme not in ("tcp", "tls"):
        raise ValueError(f"secure variant: rendezvous {spec.rendezvous} is not tcp/ or tls/")
    d = Path(secure_dir).resolve()
    if not (d / "ca.pem").is_file():
        raise ValueError(f"secure variant: {d} holds no credentials: run `zennav certs {secure_dir}`")
    return replace(spec, rendezvous=f"tls/{address}", mode="client", secure_dir=str(d))


def _resolve(cmd: list, spec: LaunchSpec) -> list:
    subst = {"python": sys.executable, "rendezvous": spec.rendezvous, "vehicle": spec.vehicle, "keys": spec.keys,
             "state": spec.state}
    out = [c.format(**subst) for c in cmd]
    if out and out[0].startswith("zennav"):
        cand = Path(sys.executable).parent / out[0]
        if cand.exists():
            out[0] = str(cand)
    return out


class Child:
    def __init__(self, spec: ServiceSpec):
        self.spec = spec
        self.proc: subprocess.Popen | None = None
        self.restarts = 0
        self.started_at = 0.0
        self.readers: list[threading.Thread] = []
        self.gave_up = False
        self.finished = False


class Launcher:
    def __init__(self, spec: LaunchSpec, out=None, bus_factory=None):
        self.spec = spec
        self.out = out or sys.stdout
        self._out_lock = threading.Lock()
        self.children = {s.name: Child(s) for s in spec.services}
        self._stop = threading.Event()
        self._wake = threading.Event()
        self.bus = None
        self._bus_factory = bus_factory
        self.width = max([len(s.name) for s in spec.services] + [6])
        self.alive: set[str] = set()

    # ------------------------------------------------------------------ output
    def say(self, name: str, line: str) -> None:
        with self._out_lock:
            self.out.write(f"[{name:<{self.width}}] {line.rstrip()}\n")
            self.out.flush()

    def _pump(self, name: str, stream) -> None:
        for raw in iter(stream.readline, b""):
            self.say(name, raw.decode(errors="replace"))
        stream.close()

    # ------------------------------------------------------------------ processes
    def _env(self, s: ServiceSpec) -> dict:
        env = dict(os.environ)
        env.update({"ZENNAV_CONNECT": self.spec.rendezvous, "ZENNAV_VEHICLE": self.spec.vehicle,
                    "ZENNAV_MODE": self.spec.mode, "PYTHONUNBUFFERED": "1"})
        if self.spec.secure_dir:
            env.update({"ZENNAV_SECURE_DIR": self.spec.secure_dir, "ZENNAV_IDENTITY": s.identity})
        env.update({k: str(v) for k, v in s.env.items()})
        return env

    def start(self, c: Child) -> None:
        cmd = _resolve(c.spec.command, self.spec)
        c.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL,
                                  env=self._env(c.spec), start_new_session=True, preexec_fn=pdeath.preexec())
        c.started_at = time.monotonic()
        c.finished = False
        c.readers = [threading.Thread(target=self._pump, args=(c.spec.name, st), daemon=True)
                     for st in (c.proc.stdout, c.proc.stderr)]
        for t in c.readers:
            t.start()
        self.say("launch", f"started {c.spec.name} (pid {c.proc.pid}): {' '.join(cmd)}")

    def _on_alive(self, service: str, alive: bool) -> None:
        if alive:
            self.alive.add(service)
        else:
            self.alive.discard(service)
            if not self._stop.is_set() and any(c.spec.alive_name == service for c in self.children.values()):
                self.say("launch", f"{service} is DOWN (liveliness lost)")
        self._wake.set()

    def _ensure_bus(self):
        if self.bus is None:
            if self._bus_factory is not None:
                self.bus = self._bus_factory()
            else:
                from .bus import Bus

                client = self.spec.mode == "client"  # a set on another host than its router: a client of it
                self.bus = Bus(f"launch-{os.getpid()}", self.spec.vehicle, mode=self.spec.mode,
                               connect=[self.spec.rendezvous], listen=None if client else ["tcp/127.0.0.1:0"],
                               token=False, identity="launch", secure_dir=self.spec.secure_dir)
            self.bus.watch_alive(self._on_alive)
        return self.bus

    def run(self, until: str | None = None) -> int:
        """Start everything (each service once the services in its ``after`` are alive), wait until every
        required service is alive, then supervise until Ctrl-C/SIGTERM or until service ``until`` exits.
        Returns 0 when stopped cleanly, 1 when the set could not be brought up."""
        restore_signals = (on_stop_signals(lambda _name: self._request_stop())
                           if threading.current_thread() is threading.main_thread() else None)
        try:
            return self._run(until)
        finally:
            if restore_signals is not None:
                restore_signals()

    def _run(self, until: str | None) -> int:
        t0 = time.monotonic()
        deadline = t0 + self.spec.up_timeout_s
        try:
            self.say("launch", f"{self.spec.name}: {len(self.children)} services, rendezvous "
                               f"{self.spec.rendezvous}, vehicle {self.spec.vehicle}")
            # a peer of the rendezvous retries in the background; a client waits for it: start what waits for
            # nothing (the router of a secure set) before
            first = [c for c in self.children.values() if not c.spec.after] if self.spec.mode == "client" else []
            for c in first:
                self.start(c)
            self._ensure_bus()
            for c in self.children.values():
                if c in first:
                    continue
                while not all(self._is_alive(a) for a in c.spec.after):
                    if self._stop.is_set():
                        return self._shutdown(0)
                    if time.monotonic() > deadline:
                        self.say("launch", f"timeout: {c.spec.name} waits for "
                                           f"{[a for a in c.spec.after if not self._is_alive(a)]}")
                        return self._shutdown(1)
                    self._wait_event(0.2)
                    if self._check_children(until):
                        return self._shutdown(0)
                if self._stop.is_set():
                    return self._shutdown(0)
                self.start(c)
            need = [c.spec.alive_name for c in self.children.values() if not c.spec.optional]
            while not self._stop.is_set():
                missing = [n for n in need if not self._is_alive(n) and not self.children_by_alive(n).finished]
                if not missing:
                    self.say("launch", f"all {len(need)} services up in {time.monotonic() - t0:.1f} s: "
                                       f"{', '.join(need)}")
                    break
                if time.monotonic() > deadline:
                    self.say("launch", f"timeout after {self.spec.up_timeout_s:.0f} s waiting for {missing}")
                    return self._shutdown(1)
                self._wait_event(0.2)
                if self._check_children(until):
                    return self._shutdown(0)
            while not self._stop.is_set():
                self._wait_event(0.5)
                if self._check_children(until):
                    break
            return self._shutdown(0)
        except Exception as e:
            self.say("launch", f"error: {type(e).__name__}: {e}")
            return self._shutdown(1)

    def children_by_alive(self, alive_name: str) -> Child:
        return next(c for c in self.children.values() if c.spec.alive_name == alive_name)

    def _is_alive(self, name: str) -> bool:
        return name in self.alive

    def _wait_event(self, timeout: float) -> None:
        self._wake.wait(timeout)
        self._wake.clear()

    def _request_stop(self) -> None:
        self._stop.set()
        self._wake.set()

    def _check_children(self, until: str | None = None) -> bool:
        """Report exits and restart per policy; True when ``until`` has exited."""
        for c in self.children.values():
            p = c.proc
            if p is None or c.finished or p.poll() is None:
                continue
            rc = p.returncode
            c.finished = True
            for t in c.readers:
                t.join(1.0)
            how = f"exit code {rc}" if rc >= 0 else f"signal {signal.Signals(-rc).name}"
            failed = rc != 0
            if until and c.spec.name == until:
                self.say("launch", f"{c.spec.name} finished ({how})")
                return True
            if not failed and c.spec.exit_ok:
                self.say("launch", f"{c.spec.name} finished ({how})")
                continue
            self.say("launch", f"{c.spec.name} DIED ({how})" if failed else f"{c.spec.name} exited ({how})")
            want = c.spec.restart == "always" or (c.spec.restart == "on-failure" and failed)
            if want and not self._stop.is_set():
                if c.restarts >= c.spec.max_restarts:
                    self.say("launch", f"{c.spec.name}: gave up after {c.restarts} restarts")
                    c.gave_up = True
                    continue
                c.restarts += 1
                self.say("launch", f"restarting {c.spec.name} ({c.restarts}/{c.spec.max_restarts})")
                self.start(c)
        return False

    def _shutdown(self, code: int) -> int:
        self._stop.set()
        running = [(c, p) for c in self.children.values() if (p := c.proc) is not None and p.poll() is None]
        if running:
            self.say("launch", f"stopping {', '.join(c.spec.name for c, _ in running)}")
        for _, p in reversed(running):
            try:
                p.send_signal(signal.SIGTERM)
            except ProcessLookupError:
                pass
        deadline = time.monotonic() + self.spec.stop_timeout_s
        for c, p in reversed(running):
            try:
                p.wait(max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                self.say("launch", f"{c.spec.name} did not stop in {self.spec.stop_timeout_s:.0f} s: killing")
                p.kill()
                p.wait(5)
        for c in self.children.values():
            for t in c.readers:
                t.join(1.0)
        if self.bus is not None:
            self.bus.close()
        self.say("launch", f"stopped ({'ok' if code == 0 else 'error'})")
        return code


def launch_main(path, rendezvous: str | None = None, vehicle: str | None = None, until: str | None = None,
                secure_dir: str | None = None) -> int:
    spec = load_launch(path, {"rendezvous": rendezvous, "vehicle": vehicle})
    if secure_dir:
        spec = secure_variant(spec, secure_dir)
    return Launcher(spec).run(until=until)
