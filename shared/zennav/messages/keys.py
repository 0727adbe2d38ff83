"""Key expressions and QoS of the key space (ARCHITECTURE.md section 4): ``zennav/@v1/<vehicle>/...``.

Key grammar, ``<base> = zennav/@v1/<vehicle>``::

    <base>/sensor/imu/<id>        imu, imu_batch  IMU increments (angle [rad], velocity [m/s]) over (t_prev, t_ns]
    <base>/sensor/gnss/<id>       gnss            GNSS fix (llh [rad, rad, m], NED std, optional NED velocity)
    <base>/sensor/dvl/<id>        dvl             Doppler velocity log: 4 beam velocities [m/s] + validity, or the
                                                  velocity in the DVL frame [m/s] + validity
    <base>/sensor/depth/<id>      depth           pressure depth [m, positive down]
    <base>/sensor/stream          stream_start / stream_end   start (sensor description, initial state) and end
    <base>/sensor/history         (queryable)     the ingest's last sensor messages by cseq range, for a consumer
                                                  that lacks some (zennav.nodes.ingest.History; HISTORY_QOS)
    <base>/attitude               attitude        attitude filter output at IMU rate
    <base>/nav/solution           nav_solution    navigation solution at IMU rate
    <base>/nav/aid/<source>       aid_report      one aid source's status record (gnss_pos, gnss_vel, ...)
    <base>/nav/status             nav_status      ins health: GNSS state, counters, stream progress
    <base>/nav/<prefix>/...       the same three nav streams of a second ins (``zennav-ins --nav-prefix``)
    <base>/learn/samples          learn_sample    training pairs emitted while GNSS is good (ins -> trainer)
    <base>/learn/query            learn_query     prediction requests while GNSS is lost (ins -> predictor)
    <base>/learn/model/<name>     model_params    versioned parameter sets (trainer -> predictor)
    <base>/learn/correction       correction      the answer to one learn_query (predictor -> ins)
    <base>/svc/<service>/status   service_status  per-service heartbeat: state, counters, rejections
    <base>/@alive/<service>       (liveliness token, no payload)
"""
from __future__ import annotations

import re
from dataclasses import dataclass

ROOT = "zennav/@v1"
ALIVE = "@alive"
ENCODING = "application/msgpack"

CHUNK = re.compile(r"^[A-Za-z0-9_\-.]+$")
NAV_STREAM_NAMES = ("solution", "aid", "status")  # not allowed as a nav prefix


def check_chunk(name: str, what: str = "name") -> str:
    """A vehicle/id/service/model name must be one plain key chunk (no '/', '*', '$', '?', '#', '@')."""
    if not isinstance(name, str) or not CHUNK.match(name):
        raise ValueError(f"invalid {what} {name!r}: use letters, digits, '_', '-', '.'")
    return name


class Keys:
    """Key expressions of one vehicle (``zennav/@v1/<vehicle>/...``). ``nav_prefix`` moves the ins's output
    streams (solution, status, aid) to ``<base>/nav/<nav_prefix>/...`` so that a second ins can run beside the
    first on the same sensor stream; every other key is unchanged."""

    def __init__(self, vehicle: str = "car", nav_prefix: str = ""):
        self.vehicle = check_chunk(vehicle, "vehicle")
        self.base = f"{ROOT}/{vehicle}"
        if nav_prefix in NAV_STREAM_NAMES:
            raise ValueError(f"invalid nav prefix {nav_prefix!r}: {NAV_STREAM_NAMES} name nav streams")
        self.nav = f"{self.base}/nav/{check_chunk(nav_prefix, 'nav prefix')}" if nav_prefix else f"{self.base}/nav"

    def imu(self, id: str = "0") -> str:
        return f"{self.base}/sensor/imu/{check_chunk(str(id), 'imu id')}"

    def gnss(self, id: str = "0") -> str:
        return f"{self.base}/sensor/gnss/{check_chunk(str(id), 'gnss id')}"

    def dvl(self, id: str = "0") -> str:
        return f"{self.base}/sensor/dvl/{check_chunk(str(id), 'dvl id')}"

    def depth(self, id: str = "0") -> str:
        return f"{self.base}/sensor/depth/{check_chunk(str(id), 'depth id')}"

    def stream(self) -> str:
        return f"{self.base}/sensor/stream"

    def sensor_history(self) -> str:
        return f"{self.base}/sensor/history"

    def sensors(self) -> str:
        return f"{self.base}/sensor/**"

    def attitude(self) -> str:
        return f"{self.base}/attitude"

    def nav_solution(self) -> str:
        return f"{self.nav}/solution"

    def nav_aid(self, source: str = "*") -> str:
        return f"{self.nav}/aid/{source if source == '*' else check_chunk(source, 'aid source')}"

    def nav_status(self) -> str:
        return f"{self.nav}/status"

    def learn_samples(self) -> str:
        return f"{self.base}/learn/samples"

    def learn_model(self, name: str = "*") -> str:
        return f"{self.base}/learn/model/{name if name == '*' else check_chunk(name, 'model name')}"

    def learn_query(self) -> str:
        return f"{self.base}/learn/query"

    def learn_correction(self) -> str:
        return f"{self.base}/learn/correction"

    def svc_status(self, service: str = "*") -> str:
        return f"{self.base}/svc/{service if service == '*' else check_chunk(service, 'service')}/status"

    def alive(self, service: str = "*") -> str:
        return f"{self.base}/{ALIVE}/{service if service == '*' else check_chunk(service, 'service')}"

    def all(self) -> str:
        return f"{self.base}/**"

    def rel(self, key: str) -> str:
        """Key relative to this vehicle's base ('' when it is not under it)."""
        p = self.base + "/"
        return key[len(p):] if key.startswith(p) else ""

    def nav_prefix_of(self, key: str) -> str:
        """The nav prefix of a nav key (<base>/nav/<prefix>/...; '' for the ins's own and for other keys)."""
        parts = self.rel(key).split("/")
        return parts[1] if len(parts) > 2 and parts[0] == "nav" and parts[1] not in NAV_STREAM_NAMES else ""

    def service_of_alive(self, key: str) -> str:
        return key.rsplit("/", 1)[-1]


@dataclass(frozen=True)
class QoS:
    """QoS of a stream, in zenoh terms (mapped to zenoh enums in zennav.bus).

    reliability: "reliable" | "best_effort"; congestion: "block" (never drop; the publisher waits) |
    "drop"; priority: a zenoh Priority name; express: send at once, no batching;
    channel: the subscriber-side queue, "fifo" (bounded, lossless: a full queue back-pressures the sender)
    or "ring" (keeps the newest, for monitors); latest: the publisher also serves its last value to queries.
    """

    reliability: str = "reliable"
    congestion: str = "block"
    priority: str = "DATA"
    express: bool = False
    channel: str = "fifo"
    latest: bool = False


@dataclass(frozen=True)
class Stream:
    """One stream of the key space: relative key pattern, schemas allowed on it, time policy, QoS."""

    name: str
    pattern: str  # regex on the key relative to zennav/@v1/<vehicle>/
    schemas: tuple
    time: str  # "strict" (t_ns increasing), "nondecreasing", "cseq" (ordered by the consumer's cseq merge), "none"
    qos: QoS


# A query of sensor/history and its replies (they take the query's QoS in zenoh 1.x): blocking, so that a burst of
# a thousand replies waits for the link instead of being dropped (the default, congestion "drop", lost them all).
HISTORY_QOS = QoS("reliable", "block", "DATA_HIGH")

_NAV = r"nav/(?:[A-Za-z0-9_\-.]+/)?"  # an optional nav prefix chunk (Keys.nav_prefix)

# Sensor keys share one priority so that they stay in publish order (the cseq merge does not depend on it).
STREAMS: tuple[Stream, ...] = (
# Their time order is the consumers' cseq merge's ("cseq": zennav.stream checks the stream's time chain at each
# sample's turn), not the validator's: a validator that remembers the latest time a source claimed lets one
# far-future sample make every later one look late.
    Stream("sensor/imu", r"sensor/imu/[^/]+", ("imu", "imu_batch"), "cseq", QoS("reliable", "block", "DATA_HIGH")),
    Stream("sensor/gnss", r"sensor/gnss/[^/]+", ("gnss",), "cseq", QoS("reliable", "block", "DATA_HIGH")),
    Stream("sensor/dvl", r"sensor/dvl/[^/]+", ("dvl",), "cseq", QoS("reliable", "block", "DATA_HIGH")),
    Stream("sensor/depth", r"sensor/depth/[^/]+", ("depth",), "cseq", QoS("reliable", "block", "DATA_HIGH")),
    Stream("sensor/stream", r"sensor/stream", ("stream_start", "stream_end"), "cseq",
           QoS("reliable", "block", "DATA_HIGH", latest=True)),
    Stream("attitude", r"attitude", ("attitude",), "strict", QoS("reliable", "block", "DATA_HIGH", latest=True)),
    Stream("nav/solution", _NAV + r"solution", ("nav_solution", "nav_solution_batch"), "strict",
           QoS("reliable", "block", "DATA_HIGH", express=True, latest=True)),
    Stream("nav/aid", _NAV + r"aid/[^/]+", ("aid_report",), "nondecreasing", QoS("reliable", "block", "DATA")),
    Stream("nav/status", _NAV + r"status", ("nav_status",), "nondecreasing",
           QoS("reliable", "drop", "DATA", latest=True)),
    Stream("learn/samples", r"learn/samples", ("learn_sample",), "nondecreasing", QoS("reliable", "block", "DATA_LOW")),
    Stream("learn/query", r"learn/query", ("learn_query",), "nondecreasing",
           QoS("reliable", "block", "INTERACTIVE_HIGH", express=True)),
    Stream("learn/model", r"learn/model/[^/]+", ("model_params",), "none",
           QoS("reliable", "block", "DATA", latest=True)),
    Stream("learn/correction", r"learn/correction", ("correction",), "nondecreasing",
           QoS("reliable", "block", "INTERACTIVE_HIGH", express=True, latest=True)),
    Stream("svc/status", r"svc/[^/]+/status", ("service_status",), "none",
           QoS("reliable", "drop", "BACKGROUND", latest=True)),
)
_STREAM_RE = [(re.compile(s.pattern + r"$"), s) for s in STREAMS]
STREAM_BY_NAME = {s.name: s for s in STREAMS}

_STREAM_CACHE: dict[str, Stream | None] = {}


def stream_of(key: str) -> Stream | None:
    """The Stream a full key belongs to (None for keys outside the grammar)."""
    try:
        return _STREAM_CACHE[key]
    except KeyError:
        pass
    s = _stream_of(key)
    if len(_STREAM_CACHE) < 10_000:
        _STREAM_CACHE[key] = s
    return s


def _stream_of(key: str) -> Stream | None:
    parts = key.split("/", 3)
    if len(parts) < 4 or f"{parts[0]}/{parts[1]}" != ROOT:
        return None
    rel = parts[3]
    for rx, s in _STREAM_RE:
        if rx.match(rel):
            return s
    return None


def qos_of(key: str) -> QoS:
    s = stream_of(key)
    return s.qos if s is not None else QoS()


def qos_table() -> list[dict]:
    """The QoS of every stream, for docs and `zennav monitor --qos`."""
    return [dict(stream=s.name, schemas=list(s.schemas), time=s.time, **s.qos.__dict__) for s in STREAMS]
