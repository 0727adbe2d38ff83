"""The secure bus with real processes: a `zennav router` holding deploy/secure/router.json5 (mutual TLS,
user/password, default-deny access control), credentials from `zennav certs`, clients in other processes
(put_node.py) and an authorised subscriber in the test process that counts what reaches it."""
from __future__ import annotations

import json
import socket
import subprocess
import threading
import time
from collections import Counter
from pathlib import Path

import pytest
from zennav_harness import PY, Proc, free_port, wait_until

from zennav.bus import Bus
from zennav.certs import make_certs

PUT_NODE = str(Path(__file__).with_name("put_node.py"))
KEYS = {"imu": "zennav/@v1/car/sensor/imu/0", "gnss": "zennav/@v1/car/sensor/gnss/0",
        "stream": "zennav/@v1/car/sensor/stream", "nav": "zennav/@v1/car/nav/solution",
        "model": "zennav/@v1/car/learn/model/m", "correction": "zennav/@v1/car/learn/correction"}
OWNS = {"ingest": {"imu", "gnss", "stream"}, "ins": {"nav"}, "trainer": {"model"}, "predictor": {"correction"},
        "attitude": set(), "monitor": set()}
COUNT = 50


class SecureBus:
    """Credentials, a router process on a tls/ loopback port and the test's observer session (identity record,
    authorised to read every key) counting samples per (key, first word of the payload)."""

    def __init__(self, tmp: Path):
        self.creds = tmp / "creds"
        make_certs(self.creds)
        self.tmp = tmp
        self.port = free_port()
        self.endpoint = f"tls/127.0.0.1:{self.port}"
        self.env = {**__import__("os").environ, "PYTHONUNBUFFERED": "1", "ZENNAV_SECURE_DIR": str(self.creds)}
        for k in ("ZENNAV_CONNECT", "ZENNAV_LISTEN", "ZENNAV_MODE", "ZENNAV_ZENOH_CONFIG", "ZENNAV_IDENTITY"):
            self.env.pop(k, None)
        exe = str(Path(PY).parent / "zennav")
        self.router = Proc("router", [exe, "router", "--listen", self.endpoint], tmp / "router.log", self.env)
        wait_until(self._listening, 30, "the router's tls listener")
        self.got: Counter[tuple[str, str]] = Counter()
        self._lock = threading.Lock()
        self.bus = Bus("record", mode="client", connect=[self.endpoint], token=False, identity="record",
                       secure_dir=self.creds)
        self.bus.subscribe("zennav/@v1/car/**", self._on, validate=False, channel="fifo", name="observer")

    def _listening(self) -> bool:
        if not self.router.alive():
            pytest.fail(f"router exited:\n{self.router.text()[-3000:]}")
        with socket.socket() as s:
            return s.connect_ex(("127.0.0.1", self.port)) == 0

    def _on(self, key: str, payload: bytes, recv_ns: int) -> None:
        with self._lock:
            self.got[(key, payload.split(b" ", 1)[0].decode(errors="replace"))] += 1

    def received(self, tag: str) -> dict[str, int]:
        """Samples received per key name (KEYS) from the client that tagged its payloads ``tag``."""
        with self._lock:
            return {name: self.got[(key, tag)] for name, key in KEYS.items()}

    def put(self, identity: str, *extra: str, tag: str | None = None, endpoint: str | None = None) -> dict:
        """Run put_node.py (COUNT payloads on every key) as ``identity``; its JSON result."""
        return self.put_all({tag or identity: (identity, extra, endpoint)})[tag or identity]

    def put_all(self, cases: dict[str, tuple]) -> dict[str, dict]:
        """put() for every tag -> (identity, extra arguments, endpoint or None) at once (concurrent processes: a
        refused one waits for its connect timeout); the JSON result per tag."""
        procs = {}
        for tag, (identity, extra, endpoint) in cases.items():
            argv = [PY, PUT_NODE, "--endpoint", endpoint or self.endpoint, "--identity", identity, "--count",
                    str(COUNT), "--tag", tag, *extra]
            for key in KEYS.values():
                argv += ["--key", key]
            procs[tag] = subprocess.Popen(argv, env=self.env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                          text=True)
        out = {}
        for tag, p in procs.items():
            stdout, stderr = p.communicate(timeout=60)
            assert p.returncode == 0, (tag, stderr[-3000:])
            out[tag] = json.loads(stdout.strip().splitlines()[-1])
        return out

    def close(self) -> None:
        self.bus.close()
        self.router.stop()


@pytest.fixture(scope="module")
def secure(tmp_path_factory):
    s = SecureBus(tmp_path_factory.mktemp("secure"))
    yield s
    s.close()


def test_only_the_owner_of_a_key_can_put_on_it(secure):
    """Each identity (all at once, one client each) puts on every sensor, navigation, model and learned-answer
    key: the authorised subscriber gets exactly the keys the identity owns (all COUNT samples) and nothing of the
    others."""
    for identity, res in secure.put_all({i: (i, (), None) for i in sorted(OWNS)}).items():
        assert res["opened"], (identity, res)
    wait_until(lambda: all(secure.received(i)[n] >= COUNT for i, names in OWNS.items() for n in names), 20,
               "every owner's authorised samples")
    time.sleep(1.0)  # anything denied would have arrived by now
    for identity, names in OWNS.items():
        assert secure.received(identity) == {name: COUNT if name in names else 0 for name in KEYS}, identity


def test_credentials_of_two_identities_do_not_combine(secure):
    """The ins's certificate with the ingest's user and password: the session opens (both are valid), but no
    subject matches both (certificate common name AND user name), so every put is denied."""
    pw = (secure.creds / "ingest.secret").read_text()
    res = secure.put("ins", "--user", "ingest", "--password", pw, tag="mixed")
    assert res["opened"], res
    time.sleep(1.0)
    assert secure.received("mixed") == dict.fromkeys(KEYS, 0)


def test_unauthenticated_clients_are_refused(secure, tmp_path):
    """TLS without a client certificate, a certificate of another CA (common name ingest), a wrong password,
    no password, plain TCP: the router refuses the session and nothing is received."""
    rogue = tmp_path / "rogue"
    make_certs(rogue, identities=("ingest",))
    cases = {
        "nocert": ("ingest", ("--no-cert",), None),
        "rogueca": ("ingest", ("--cert", str(rogue / "ingest.pem"), "--key-file", str(rogue / "ingest.key")), None),
        "badpw": ("ingest", ("--password", "not-the-password"), None),
        "otherpw": ("ingest", ("--password", (secure.creds / "ins.secret").read_text()), None),
        "tcp": ("ingest", (), f"tcp/127.0.0.1:{secure.port}"),
    }
    for tag, res in secure.put_all(cases).items():
        assert not res["opened"], (tag, res)
    time.sleep(1.0)
    for tag in cases:
        assert secure.received(tag) == dict.fromkeys(KEYS, 0), tag
    assert secure.router.alive()


@pytest.mark.parametrize("identity", ["ingest", "ins"])
def test_a_peer_gets_the_same_rules_as_a_client(secure, identity):
    """A zenoh peer (not a client) connected to the router is subject to the same rules: the services of the
    secure variant are clients and listen nowhere, so the router is the only way in."""
    res = secure.put(identity, "--peer", tag=f"peer-{identity}")
    assert res["opened"], res
    wait_until(lambda: all(secure.received(f"peer-{identity}")[n] >= COUNT for n in OWNS[identity]), 20,
               f"{identity}'s authorised samples as a peer")
    time.sleep(1.0)
    assert secure.received(f"peer-{identity}") == {n: COUNT if n in OWNS[identity] else 0 for n in KEYS}
