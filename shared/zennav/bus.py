"""The Zenoh transport of zennav: the only module that imports zenoh.

- ``open_config`` builds a zenoh Config from a file in deploy/ (``zenoh-peer.json5``, ``zenoh-client.json5``,
  ``zenoh-router.json5``) with endpoint overrides from arguments or the environment
  (``ZENNAV_ZENOH_CONFIG``, ``ZENNAV_MODE``, ``ZENNAV_CONNECT``, ``ZENNAV_LISTEN``; comma-separated endpoints).
  Secure variant (``ZENNAV_SECURE_DIR``: credentials of ``zennav certs DIR``): deploy/secure/client.json5 or
  router.json5 (mutual TLS, user/password, the router's access control), tls/ endpoints only, the identity's
  certificate and password (``ZENNAV_IDENTITY``, default the service name).
- ``Bus`` is one session of one service: publishers and subscribers with the stream's QoS from
  ``zennav.messages``, a liveliness token ``zennav/@v1/<vehicle>/@alive/<service>``, liveliness watching,
  queryables serving the latest value of a stream or a service's own answers (``serve``), queries for late
  joiners and ranges, and clean shutdown.

Threading: every subscription receives into a zenoh channel (``fifo``: bounded and lossless, a full queue
back-pressures the sender through reliable/blocking transport; ``ring``: keeps the newest) and one worker
thread per subscription drains it, decodes, validates and calls the service's callback (a nav_solution_batch
once per solution it holds, zennav.messages.solutions; raw subscribers get its bytes). A full fifo stops its
link's receiving: for a client (every flow through one link to the router) each fifo subscription therefore
gets a session, a link, of its own, so one full queue holds back only its own stream. On one shared link it
would hold back every stream behind it, and flows that cross through the router deadlock (the ins's solutions
wait behind sensor samples on the link to the attitude, whose attitudes wait behind sensor samples on the link
to the ins) until zenoh closes the link (wait_before_close). Peers keep one session: their links are per pair.
No Python code runs in zenoh's network threads except the queryables: the latest values reply with cached
bytes, ``serve``'s answers with what they look up (the ingest's history: a slice of its last messages). With
``serial=True`` (default) the callbacks of one Bus never run concurrently (one lock), so
services need no locking of their own.
"""
from __future__ import annotations

import atexit
import json
import logging
import os
import threading
import time
import uuid
from collections import Counter
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, Literal, overload

import zenoh
import zenoh.ext

from . import messages as M

log = logging.getLogger("zennav.bus")

DEPLOY_DIR = Path(__file__).resolve().parents[2] / "deploy"
CONFIG_FILES = {"peer": "zenoh-peer.json5", "client": "zenoh-client.json5", "router": "zenoh-router.json5"}
SECURE_CONFIG_FILES = {"client": "secure/client.json5", "router": "secure/router.json5"}
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"

_PRIORITY = {n: getattr(zenoh.Priority, n) for n in ("REAL_TIME", "INTERACTIVE_HIGH", "INTERACTIVE_LOW", "DATA_HIGH",
                                                      "DATA", "DATA_LOW", "BACKGROUND")}
_CONGESTION = {"block": zenoh.CongestionControl.BLOCK, "drop": zenoh.CongestionControl.DROP}
_RELIABILITY = {"reliable": zenoh.Reliability.RELIABLE, "best_effort": zenoh.Reliability.BEST_EFFORT}
_ENCODING = zenoh.Encoding(M.ENCODING)

_log_inited = False

MsgCallback = Callable[[str, dict, int], object]  # (key, validated message map, recv_ns); the result is ignored
RawCallback = Callable[[str, bytes, int], object]  # (key, payload as received, recv_ns); the result is ignored


def _init_zenoh_log() -> None:
    global _log_inited
    if not _log_inited:
        zenoh.init_log_from_env_or("error")
        _log_inited = True


def _split(v) -> list[str] | None:
    if v is None:
        return None
    if isinstance(v, str):
        return [e.strip() for e in v.split(",") if e.strip()]
    return [str(e) for e in v]


def config_path(mode: str | None = None, config_file: str | os.PathLike | None = None,
                secure: bool = False) -> Path | None:
    """The config file to use: explicit > ZENNAV_ZENOH_CONFIG > deploy/zenoh-<mode>.json5, or with secure
    deploy/secure/<client|router>.json5 (None if absent)."""
    path = config_file or os.environ.get("ZENNAV_ZENOH_CONFIG")
    if path:
        return Path(path)
    if secure:
        p = DEPLOY_DIR / SECURE_CONFIG_FILES["router" if mode == "router" else "client"]
    else:
        p = DEPLOY_DIR / CONFIG_FILES.get(mode or "peer", CONFIG_FILES["peer"])
    return p if p.exists() else None


def open_config(mode: str | None = None, config_file=None, connect=None, listen=None, *,
                identity: str | None = None, secure_dir: str | os.PathLike | None = None) -> zenoh.Config:
    """zenoh Config from a deploy/ file, then mode/endpoint overrides (arguments win over the environment).
    secure_dir (else ZENNAV_SECURE_DIR): the secure variant with the credentials of ``identity`` (else
    ZENNAV_IDENTITY) from that directory; raises ValueError for a peer, a non-tls endpoint or missing files."""
    mode = mode or os.environ.get("ZENNAV_MODE") or None
    secure = secure_dir or os.environ.get("ZENNAV_SECURE_DIR") or None
    if secure and mode not in (None, "client", "router"):
        raise ValueError(f"secure bus: mode {mode!r} refused: services are clients of the router "
                         "(peers open direct links that bypass its access control)")
    path = config_path(mode, config_file, secure=bool(secure))
    if path is not None:
        conf = zenoh.Config.from_file(str(path))
    elif secure:
        raise ValueError(f"secure bus: no {DEPLOY_DIR / SECURE_CONFIG_FILES['client']} (run from the source tree)")
    else:  # installed without deploy/: the same defaults as deploy/zenoh-peer.json5
        conf = zenoh.Config()
        conf.insert_json5("scouting/multicast/enabled", "false")
        conf.insert_json5("connect/endpoints", f'["{DEFAULT_ENDPOINT}"]')
        conf.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
        conf.insert_json5("transport/link/tx/queue/congestion_control/block/wait_before_close", "60000000")
        conf.insert_json5("transport/link/tx/lease", "60000")
    if mode:
        conf.insert_json5("mode", f'"{mode}"')
    connect = _split(connect if connect is not None else os.environ.get("ZENNAV_CONNECT"))
    listen = _split(listen if listen is not None else os.environ.get("ZENNAV_LISTEN"))
    if secure and (bad := [e for e in (connect or []) + (listen or []) if not e.startswith("tls/")]):
        raise ValueError(f"secure bus: endpoints {bad} refused: tls/ only")
    if connect is not None:
        conf.insert_json5("connect/endpoints", _json_list(connect))
    if listen is not None:
        conf.insert_json5("listen/endpoints", _json_list(listen))
    if secure:
        _insert_credentials(conf, Path(secure), identity or os.environ.get("ZENNAV_IDENTITY") or "",
                            router=mode == "router")
    return conf


def _insert_credentials(conf: zenoh.Config, cred_dir: Path, identity: str, router: bool) -> None:
    """TLS certificate/key of ``identity`` and the CA; the router its user/password dictionary, a client its
    user name (= identity) and password (files of ``zennav certs``)."""
    identity = "router" if router else identity
    files = {"ca": cred_dir / "ca.pem", "cert": cred_dir / f"{identity}.pem", "key": cred_dir / f"{identity}.key",
             "secret": cred_dir / ("usrpwd.txt" if router else f"{identity}.secret")}
    missing = [str(p) for p in files.values() if not p.is_file()]
    if not identity or missing:
        raise ValueError(f"secure bus: no credentials for identity {identity!r} in {cred_dir} "
                         f"({', '.join(missing) or 'no ZENNAV_IDENTITY'}): run `zennav certs {cred_dir}`")
    tls = "transport/link/tls/"
    conf.insert_json5(tls + "root_ca_certificate", json.dumps(str(files["ca"].resolve())))
    for side in ("connect", "listen") if router else ("connect",):
        conf.insert_json5(tls + f"{side}_certificate", json.dumps(str(files["cert"].resolve())))
        conf.insert_json5(tls + f"{side}_private_key", json.dumps(str(files["key"].resolve())))
    if router:
        conf.insert_json5("transport/auth/usrpwd/dictionary_file", json.dumps(str(files["secret"].resolve())))
    else:
        conf.insert_json5("transport/auth/usrpwd/user", json.dumps(identity))
        conf.insert_json5("transport/auth/usrpwd/password", json.dumps(files["secret"].read_text().strip()))


def _json_list(items: Iterable[str]) -> str:
    return "[" + ",".join(f'"{e}"' for e in items) + "]"


class Publisher:
    """Publishes message maps on one key with the stream's QoS; stamps src, seq and pub_ns; optionally keeps
    the last payload and serves it to queries (late joiners)."""

    def __init__(self, bus: Bus, key: str, qos: M.QoS | None = None, latest: bool | None = None):
        self.bus = bus
        self.key = key
        self.qos = qos or M.qos_of(key)
        self._pub = self._declare(bus.session, key)
        self.seq = 0
        self.latest: bytes | None = None
        self._queryable = None
        if self.qos.latest if latest is None else latest:
            self._queryable = bus.session.declare_queryable(key, self._on_query, complete=True)

    def _declare(self, session: zenoh.Session, key: str) -> Any:
        return session.declare_publisher(
            key, encoding=_ENCODING, congestion_control=_CONGESTION[self.qos.congestion],
            priority=_PRIORITY[self.qos.priority], express=self.qos.express,
            reliability=_RELIABILITY[self.qos.reliability])

    def put(self, msg: dict) -> bytes:
        """Stamp the header (src, seq, pub_ns), encode and publish; returns the payload."""
        msg["src"] = self.bus.src
        msg["seq"] = self.seq
        msg["pub_ns"] = time.time_ns()
        payload = M.encode(msg)
        self._pub.put(payload)
        self.seq += 1
        if self._queryable is not None:
            self.latest = payload
        return payload

    def put_packed(self, pack: Callable[..., bytes], *fields) -> bytes:
        """Publish pack(*fields, src, seq, pub_ns), a message packed without a map (zennav.messages.SolutionPacker),
        stamped as put stamps one; returns the payload."""
        payload = pack(*fields, self.bus.src, self.seq, time.time_ns())
        self._pub.put(payload)
        self.seq += 1
        if self._queryable is not None:
            self.latest = payload
        return payload

    def put_raw(self, payload: bytes, attachment: bytes | None = None) -> None:
        """Publish bytes as they are (bus replay, tests injecting bad payloads, the ROS 2 bridge's CDR with its
        rmw_zenoh attachment)."""
        self._pub.put(payload, attachment=attachment)
        if self._queryable is not None:
            self.latest = payload

    @property
    def matching(self) -> bool:
        """Whether a subscriber matches this key now (zenoh's matching status)."""
        return bool(self._pub.matching_status.matching)

    def _on_query(self, query) -> None:  # zenoh thread: reply with cached bytes only
        payload = self.latest
        if payload is not None:
            try:
                query.reply(self.key, payload, encoding=_ENCODING)
            except Exception:  # query may be gone
                pass

    def close(self) -> None:
        for obj in (self._queryable, self._pub):
            if obj is not None:
                try:
                    obj.undeclare()
                except Exception:
                    pass


class Subscription:
    """A zenoh subscriber draining into a worker thread (see the module docstring)."""

    def __init__(self, bus: Bus, keyexpr: str, callback: MsgCallback | RawCallback, *, validate: bool,
                 channel: str, capacity: int, name: str):
        self.bus = bus
        self.keyexpr = keyexpr
        # a MsgCallback with validate, else a RawCallback (Bus.subscribe's overloads pair them)
        self.callback: Callable[[str, Any, int], object] = callback
        self.validate = validate
        self.validator = M.Validator()
        self.received = 0
        handler = zenoh.handlers.FifoChannel(capacity) if channel == "fifo" else zenoh.handlers.RingChannel(capacity)
        # a client's fifo on a link of its own (module docstring)
        self._session = zenoh.open(bus._open_config()) if channel == "fifo" and bus.client else None
        self._sub = self._declare(self._session or bus.session, keyexpr, handler)
        self._handler = self._sub.handler
        self._thread = threading.Thread(target=self._run, name=f"zennav-sub-{name}", daemon=True)
        self._thread.start()

    def _declare(self, session: zenoh.Session, keyexpr: str, handler: Any) -> Any:
        return session.declare_subscriber(keyexpr, handler)

    def _run(self) -> None:
        h = self._handler
        lock = self.bus._cb_lock
        cb = self.callback
        validate = self.validate
        check = self.validator.check
        put_kind = zenoh.SampleKind.PUT
        while True:
            try:
                sample = h.recv()
            except Exception:  # channel closed: subscriber undeclared or session closed
                return
            recv_ns = time.time_ns()
            if sample.kind != put_kind:
                continue
            key = str(sample.key_expr)
            payload = sample.payload.to_bytes()
            self.received += 1
            if validate:
                value, reason = check(key, payload)
                if value is None:
                    self.bus.count_rejected(key, reason)
                    continue
            else:
                value = payload
            # a nav_solution_batch reaches a validating subscriber as the nav_solution messages it stands for
            for msg in M.solutions(value) if validate and value["schema"] == "nav_solution_batch" else (value,):
                try:
                    if lock is not None:
                        with lock:
                            cb(key, msg, recv_ns)
                    else:
                        cb(key, msg, recv_ns)
                except Exception:
                    self.bus.errors["callback"] += 1
                    log.exception("callback for %s failed", key)

    def close(self, join_timeout: float = 2.0) -> None:
        try:
            self._sub.undeclare()
        except Exception:
            pass
        if threading.current_thread() is not self._thread:
            self._thread.join(join_timeout)
        if self._session is not None:
            try:
                self._session.close()
            except Exception:
                pass


class CachedPublisher(Publisher):
    """A Publisher through zenoh's advanced publisher (zenoh.ext): it keeps its last ``cache`` samples and serves
    them to advanced subscribers (``Bus.recovering_subscribe``), which fetch them at their start (history: a
    restarted consumer gets what it missed while it was down) and when they detect a lost sample (recovery:
    the publisher's sequence numbers, with a heartbeat every ``heartbeat_s`` so that a loss of the last samples
    is seen too). A plain publisher on the same key answers ``matching`` (the advanced one has no status)."""

    def __init__(self, bus: Bus, key: str, cache: int, qos: M.QoS | None = None, latest: bool | None = None,
                 heartbeat_s: float = 0.5):
        self.cache, self.heartbeat_s = int(cache), heartbeat_s
        super().__init__(bus, key, qos, latest)
        self._probe = super()._declare(bus.session, key)

    def _declare(self, session: zenoh.Session, key: str) -> Any:
        return zenoh.ext.declare_advanced_publisher(
            session, key, encoding=_ENCODING, congestion_control=_CONGESTION[self.qos.congestion],
            priority=_PRIORITY[self.qos.priority], express=self.qos.express,
            reliability=_RELIABILITY[self.qos.reliability],
            cache=zenoh.ext.CacheConfig(self.cache, replies_config=zenoh.ext.RepliesConfig(
                congestion_control=_CONGESTION[self.qos.congestion], priority=_PRIORITY[self.qos.priority])),
            sample_miss_detection=zenoh.ext.MissDetectionConfig(heartbeat=self.heartbeat_s, sporadic_heartbeat=None),
            publisher_detection=True)

    @property
    def matching(self) -> bool:
        return bool(self._probe.matching_status.matching)

    def close(self) -> None:
        try:
            self._probe.undeclare()
        except Exception:
            pass
        super().close()


class RecoveringSubscription(Subscription):
    """A Subscription through zenoh's advanced subscriber: at its start it fetches the caches of the
    CachedPublishers already there (history), and it recovers samples it detects as lost from them (recovery,
    on the publishers' heartbeat); samples it could not recover are counted per key in ``Bus.missed``."""

    def _declare(self, session: zenoh.Session, keyexpr: str, handler: Any) -> Any:
        ext = zenoh.ext
        sub = ext.declare_advanced_subscriber(session, keyexpr, handler, history=ext.HistoryConfig(),
                                              recovery=ext.RecoveryConfig(periodic_queries=None, heartbeat=True),
                                              subscriber_detection=True)
        self._misses = sub.sample_miss_listener(self._on_miss)
        return sub

    def _on_miss(self, miss: Any) -> None:  # zenoh thread: count only
        self.bus.count_missed(self.keyexpr, int(miss.nb))

    def close(self, join_timeout: float = 2.0) -> None:
        try:
            self._misses.undeclare()
        except Exception:
            pass
        super().close(join_timeout)


class Bus:
    """One zenoh session of one service (see the module docstring).

    service: name used for the liveliness token and the status key; vehicle: the key-space vehicle;
    mode/config/connect/listen: see open_config; token: declare the liveliness token now; identity: whose
    credentials a secure bus uses (default ZENNAV_IDENTITY, else the service name); secure_dir: the secure
    variant's credentials (default ZENNAV_SECURE_DIR; see open_config).
    """

    def __init__(self, service: str, vehicle: str | None = None, *, mode: str | None = None, config=None,
                 connect=None, listen=None, token: bool = True, serial: bool = True, identity: str | None = None,
                 secure_dir: str | os.PathLike | None = None):
        _init_zenoh_log()
        self.service = M.check_chunk(service, "service")
        self.keys = M.Keys(vehicle or os.environ.get("ZENNAV_VEHICLE") or "car")
        identity = identity or os.environ.get("ZENNAV_IDENTITY") or service
        self._open_config = lambda: open_config(mode, config, connect, listen, identity=identity,
                                                secure_dir=secure_dir)
        conf = self._open_config()
        self.client = json.loads(conf.get_json("mode")) == "client"
        self.session = zenoh.open(conf)
        self.zid = str(self.session.zid())
        self.src = f"{service}.{self.zid[:12]}.{uuid.uuid4().hex[:6]}"
        self._cb_lock = threading.RLock() if serial else None
        self._subs: list[Subscription] = []
        self._pubs: dict[str, Publisher] = {}
        self._queryables: list[Any] = []  # serve()
        self.rejected: Counter[str] = Counter()
        self.rejected_by_key: Counter[tuple[str, str]] = Counter()
        self.errors: Counter[str] = Counter()
        self.missed: Counter[str] = Counter()  # key expression -> samples lost, not recovered (recovering_subscribe)
        self._rej_lock = threading.Lock()
        self._token: zenoh.LivelinessToken | None = None
        self._alive: set[str] = set()
        self._alive_cv = threading.Condition()
        self._alive_watch: tuple[zenoh.Subscriber[Any], threading.Thread] | None = None
        self._alive_listeners: list[Callable[[str, bool], None]] = []
        self._closed = False
        self._status_pub: Publisher | None = None
        if token:
            self.announce()
        atexit.register(self.close)

    # ------------------------------------------------------------------ publish / subscribe
    def publisher(self, key: str, qos: M.QoS | None = None, latest: bool | None = None) -> Publisher:
        pub = self._pubs.get(key)
        if pub is None:
            pub = self._pubs[key] = Publisher(self, key, qos, latest)
        return pub

    def cached_publisher(self, key: str, cache: int, qos: M.QoS | None = None) -> Publisher:
        """A CachedPublisher on key keeping its last ``cache`` samples for recovering subscribers (one per key)."""
        pub = self._pubs.get(key)
        if pub is None:
            pub = self._pubs[key] = CachedPublisher(self, key, cache, qos)
        return pub

    def recovering_subscribe(self, keyexpr: str, callback: MsgCallback | RawCallback, *, validate: bool = True,
                             channel: str | None = None, capacity: int = 4096,
                             name: str | None = None) -> Subscription:
        """subscribe() through a RecoveringSubscription: the publishers' caches fetched at the start and lost
        samples recovered; what could not be recovered is counted in ``missed``."""
        return self._subscribe(RecoveringSubscription, keyexpr, callback, validate, channel, capacity, name)

    def count_missed(self, keyexpr: str, n: int) -> None:
        """Count samples a recovering subscription detected as lost and could not recover (any thread)."""
        with self._rej_lock:
            self.missed[keyexpr] += n
            total = self.missed[keyexpr]
        log.warning("%d samples on %s lost (not recovered; %d in all)", n, keyexpr, total)

    @overload
    def subscribe(self, keyexpr: str, callback: MsgCallback, *, validate: Literal[True] = True,
                  channel: str | None = None, capacity: int = 4096, name: str | None = None) -> Subscription: ...

    @overload
    def subscribe(self, keyexpr: str, callback: RawCallback, *, validate: Literal[False],
                  channel: str | None = None, capacity: int = 4096, name: str | None = None) -> Subscription: ...

    def subscribe(self, keyexpr: str, callback: MsgCallback | RawCallback, *, validate: bool = True,
                  channel: str | None = None, capacity: int = 4096, name: str | None = None) -> Subscription:
        """callback(key, msg_or_bytes, recv_ns) runs on the subscription's worker thread; with validate=True
        it gets validated message maps (rejections are counted in ``rejected`` and logged), else raw bytes.
        channel defaults to the stream's QoS ("fifo" for exact keys of lossless streams, "ring" otherwise)."""
        return self._subscribe(Subscription, keyexpr, callback, validate, channel, capacity, name)

    def _subscribe(self, kind: type[Subscription], keyexpr: str, callback: MsgCallback | RawCallback, validate: bool,
                   channel: str | None, capacity: int, name: str | None) -> Subscription:
        if channel is None:
            st = M.stream_of(keyexpr)
            channel = st.qos.channel if st is not None else "ring"
        sub = kind(self, keyexpr, callback, validate=validate, channel=channel, capacity=capacity,
                   name=name or keyexpr.rsplit("/", 1)[-1])
        self._subs.append(sub)
        return sub

    def count_rejected(self, key: str, reason: str) -> None:
        """Count (per reason code and key) and log a rejected message; reason is 'code: detail'."""
        code = reason.split(":", 1)[0]
        with self._rej_lock:
            self.rejected[code] += 1
            self.rejected_by_key[(key, code)] += 1
            n = self.rejected[code]
        if n <= 5 or n % 1000 == 0:
            log.warning("rejected message on %s (#%d %s): %s", key, n, code, reason)

    @property
    def callback_lock(self) -> threading.RLock | None:
        """The lock every subscription callback of a serial bus runs under (None when not serial): a callback that
        waits for another subscription's message waits on a condition of this lock."""
        return self._cb_lock

    def rejected_counts(self) -> dict[str, int]:
        """A copy of the rejection counters (reason code -> count), safe from any thread."""
        with self._rej_lock:
            return dict(self.rejected)

    def get(self, selector: str, timeout: float = 2.0, payload: bytes | None = None,
            qos: M.QoS | None = None) -> list[tuple[str, bytes]]:
        """Query queryables (latest values, a served range) matching selector, with payload; returns (key,
        payload) of each reply. qos: the query's congestion control and priority, which its replies take (zenoh
        1.x; default: zenoh's, congestion "drop")."""
        kw = {} if qos is None else {"congestion_control": _CONGESTION[qos.congestion],
                                     "priority": _PRIORITY[qos.priority], "express": qos.express}
        out = []
        for reply in self.session.get(selector, timeout=timeout, payload=payload, **kw):
            ok = reply.ok
            if ok is not None:
                out.append((str(ok.key_expr), ok.payload.to_bytes()))
        return out

    def get_latest(self, selector: str, timeout: float = 2.0) -> list[tuple[str, dict]]:
        """Query and validate (key, message) pairs; invalid replies are counted and skipped."""
        v = M.Validator()
        out = []
        for key, payload in self.get(selector, timeout):
            msg, reason = v.check(key, payload)
            if msg is None:
                self.count_rejected(key, reason)
            else:
                out.append((key, msg))
        return out

    def serve(self, key: str, answer: Callable[[bytes], bytes | None]) -> None:
        """A queryable on key: answer(the query's payload) runs on a zenoh thread (keep it short); what it
        returns, unless None, is the one reply (on key). A failing answer is counted in ``errors``."""
        def on_query(query) -> None:
            try:
                out = answer(query.payload.to_bytes() if query.payload is not None else b"")
                if out is not None:
                    query.reply(key, out, encoding=_ENCODING)
            except Exception:  # a malformed query, or the query gone: never raise into zenoh
                self.errors["serve"] += 1
                log.exception("answering a query on %s failed", key)

        self._queryables.append(self.session.declare_queryable(key, on_query, complete=True))

    # ------------------------------------------------------------------ status / liveliness
    def announce(self) -> None:
        if self._token is None:
            self._token = self.session.liveliness().declare_token(self.keys.alive(self.service))

    def publish_status(self, state: str, detail: str = "", counters=None) -> None:
        """Publish this service's heartbeat/status (latest value served to late joiners)."""
        if self._status_pub is None:
            self._status_pub = self.publisher(self.keys.svc_status(self.service))
        with self._rej_lock:
            rejected = dict(self.rejected)
        c = dict(counters or {})
        if self.errors:
            c.update({f"error_{k}": v for k, v in self.errors.items()})
        self._status_pub.put(M.service_status_msg(self.service, state, detail, c, rejected))

    def watch_alive(self, listener: Callable[[str, bool], None] | None = None) -> None:
        """Track the services alive on this vehicle (liveliness tokens); listener(service, alive) is called
        on changes, from the watcher thread."""
        if listener is not None:
            self._alive_listeners.append(listener)
            with self._alive_cv:
                for s in sorted(self._alive):
                    listener(s, True)
        if self._alive_watch is not None:
            return
        sub = self.session.liveliness().declare_subscriber(
            self.keys.alive(), zenoh.handlers.FifoChannel(1024), history=True)
        handler = sub.handler

        def run():
            put_kind = zenoh.SampleKind.PUT
            while True:
                try:
                    sample = handler.recv()
                except Exception:
                    return
                svc = str(sample.key_expr).rsplit("/", 1)[-1]
                alive = sample.kind == put_kind
                with self._alive_cv:
                    if alive:
                        self._alive.add(svc)
                    else:
                        self._alive.discard(svc)
                    self._alive_cv.notify_all()
                for fn in list(self._alive_listeners):
                    try:
                        fn(svc, alive)
                    except Exception:
                        log.exception("liveliness listener failed")

        t = threading.Thread(target=run, name="zennav-alive", daemon=True)
        t.start()
        self._alive_watch = (sub, t)

    def alive(self) -> set[str]:
        self.watch_alive()
        with self._alive_cv:
            return set(self._alive)

    def wait_alive(self, services: Iterable[str], timeout: float | None = 30.0, alive: bool = True) -> bool:
        """Block until every named service is alive (or, alive=False, gone); False on timeout."""
        self.watch_alive()
        want = set(services)
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._alive_cv:
            while True:
                ok = want <= self._alive if alive else not (want & self._alive)
                if ok:
                    return True
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    return False
                self._alive_cv.wait(left if left is None else min(left, 1.0))

    # ------------------------------------------------------------------ info / shutdown
    def peers(self) -> list[str]:
        return [str(z) for z in self.session.info.peers_zid()]

    def routers(self) -> list[str]:
        return [str(z) for z in self.session.info.routers_zid()]

    def close(self) -> None:
        """Undeclare everything, stop the workers and close the session (idempotent, never hangs)."""
        if self._closed:
            return
        self._closed = True
        if self._token is not None:
            try:
                self._token.undeclare()
            except Exception:
                pass
        for sub in self._subs:
            sub.close()
        if self._alive_watch is not None:
            watcher, t = self._alive_watch
            try:
                watcher.undeclare()
            except Exception:
                pass
            if threading.current_thread() is not t:
                t.join(2.0)
        for pub in self._pubs.values():
            pub.close()
        for q in self._queryables:
            try:
                q.undeclare()
            except Exception:
                pass
        try:
            self.session.close()
        except Exception:
            pass
        try:
            atexit.unregister(self.close)
        except Exception:
            pass

    def __enter__(self) -> Bus:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
