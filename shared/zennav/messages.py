"""Every message zennav exchanges: schemas, key grammar, QoS per stream, codec and validation.

No zenoh here (``zennav.bus`` is the only module that imports it); this module is pure Python + msgpack
so that the schemas can be unit-tested, recorded and replayed without a network.

Wire format
-----------
Every message is a msgpack map with a header and the schema's fields::

    {"schema": "imu", "v": 1,          # schema name and version (this module is the registry)
     "t_ns": int,                       # sample time, integer ns of GPS time (DESIGN.md section 3)
     "src": str, "seq": int,            # publisher instance id and its per-key sequence number (drop detection)
     "pub_ns": int,                     # wall-clock publish time [ns since 1970] (latency measurement only)
     ...fields}

Float arrays travel as msgpack lists of float64 (Python floats; numpy arrays go through ``tolist()``), so
every value round-trips bit for bit. Integers (times, counts) are msgpack integers. Unknown extra fields
are tolerated (forward compatible within one version) but never used.

Key grammar (DESIGN.md section 4), ``<base> = zennav/@v1/<vehicle>``::

    <base>/sensor/imu/<id>        imu             IMU increments (angle [rad], velocity [m/s]) over (t_prev, t_ns]
                                  imu_batch       consecutive IMU samples in one message (ingest --batch, replay
                                                  as fast as possible only): one cseq per sample
    <base>/sensor/gnss/<id>       gnss            GNSS fix (llh [rad, rad, m], NED std, optional NED velocity)
    <base>/sensor/stream          stream_start / stream_end   start (dataset, NavConfig, InitialState) and end markers
    <base>/attitude               attitude        attitude filter output at IMU rate
    <base>/nav/solution           nav_solution    navigation solution at IMU rate
    <base>/nav/aid/<source>       aid_report      one aiding update (gnss_pos, gnss_vel, ...)
    <base>/nav/status             nav_status      ins health: GNSS state, counters, stream progress
    <base>/learn/samples          learn_sample    training pairs emitted while GNSS is good (ins -> trainer)
    <base>/learn/query            learn_query     prediction requests while GNSS is lost (ins -> predictor)
    <base>/learn/model/<name>     model_params    versioned parameter sets (trainer -> predictor; latest served to
                                                  late joiners; the wire form of zennav.learn.paramset)
    <base>/learn/correction       correction      the answer to one learn_query: prediction, 1-sigma, model name
                                                  and version (predictor -> ins)
    <base>/svc/<service>/status   service_status  per-service heartbeat: state, counters, rejections
    <base>/@alive/<service>       (liveliness token, no payload)

Ordering of the sensor channel (how the ins service reproduces the in-process replay exactly)
---------------------------------------------------------------------------------------------
ingest merges all of its sensor streams into one time-ordered sequence (sorted by ``t_ns``; at equal times
GNSS before IMU, so a fix at t is queued before the IMU sample that reaches t) and stamps every sensor
message (stream_start, imu, gnss, stream_end) with ``cseq``, one counter shared by all sensor keys of that
ingest instance (``src``). The sensor keys are published reliably with blocking congestion control and the
same priority, so in practice they arrive in publish order; the ins service does not rely on that: it
consumes messages strictly in ``cseq`` order (``SequenceMerger``), holding any that arrive early until the
missing ones come. Because the sequence totally orders IMU and GNSS, every fix with ``t_ns`` <= an IMU
sample's ``t_ns`` is handed to the core before that sample, without watermarks or timers. A gap that never
fills (only possible if a sample is really lost) is skipped once more than ``max_hold`` messages are held,
or at ``stream_end`` and is counted as ``gap``; duplicates (cseq already consumed) are counted and dropped.
An ``imu_batch`` holds N consecutive IMU samples (none of another sensor between them) with cseq c .. c+N-1;
``samples(msg)`` expands it into N ``imu`` messages, which consumers merge like any other.
``stream_start`` carries the NavConfig and InitialState, so the ins service builds its Navigator from the
same data as the in-process replay; ``stream_end`` carries the counts so consumers can prove nothing was lost.

Validation
----------
``Validator.check(key, payload)`` decodes and checks: msgpack map, header, schema known and allowed on this
key, supported version, field types, array shapes, finite numbers, and monotonic ``t_ns`` per (key, src)
(strictly increasing for sensor streams, non-decreasing for derived streams). It returns ``(msg, "")`` or
``(None, reason)``; rejections are counted per reason code (the part of the reason before ``:``) in
``Validator.rejected`` and never raise.
"""
from __future__ import annotations

import hashlib
import heapq
import math
import re
from collections import Counter
from dataclasses import dataclass, field, fields, is_dataclass
from typing import Any, Callable

import msgpack
import numpy as np

ROOT = "zennav/@v1"
ALIVE = "@alive"
ENCODING = "application/msgpack"

# ---------------------------------------------------------------------------------------------- keys
_CHUNK = re.compile(r"^[A-Za-z0-9_\-.]+$")


def check_chunk(name: str, what: str = "name") -> str:
    """A vehicle/id/service/model name must be one plain key chunk (no '/', '*', '$', '?', '#', '@')."""
    if not isinstance(name, str) or not _CHUNK.match(name):
        raise ValueError(f"invalid {what} {name!r}: use letters, digits, '_', '-', '.'")
    return name


class Keys:
    """Key expressions of one vehicle (``zennav/@v1/<vehicle>/...``)."""

    def __init__(self, vehicle: str = "car"):
        self.vehicle = check_chunk(vehicle, "vehicle")
        self.base = f"{ROOT}/{vehicle}"

    def imu(self, id: str = "0") -> str:
        return f"{self.base}/sensor/imu/{check_chunk(str(id), 'imu id')}"

    def gnss(self, id: str = "0") -> str:
        return f"{self.base}/sensor/gnss/{check_chunk(str(id), 'gnss id')}"

    def stream(self) -> str:
        return f"{self.base}/sensor/stream"

    def sensors(self) -> str:
        return f"{self.base}/sensor/**"

    def attitude(self) -> str:
        return f"{self.base}/attitude"

    def nav_solution(self) -> str:
        return f"{self.base}/nav/solution"

    def nav_aid(self, source: str = "*") -> str:
        return f"{self.base}/nav/aid/{source if source == '*' else check_chunk(source, 'aid source')}"

    def nav_status(self) -> str:
        return f"{self.base}/nav/status"

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

    def service_of_alive(self, key: str) -> str:
        return key.rsplit("/", 1)[-1]


# ---------------------------------------------------------------------------------------------- QoS
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
    time: str  # "strict" (t_ns increasing), "nondecreasing", "none"
    qos: QoS


# Sensor keys share one priority so that they stay in publish order (the cseq merge does not depend on it).
STREAMS: tuple[Stream, ...] = (
    Stream("sensor/imu", r"sensor/imu/[^/]+", ("imu", "imu_batch"), "strict", QoS("reliable", "block", "DATA_HIGH")),
    Stream("sensor/gnss", r"sensor/gnss/[^/]+", ("gnss",), "strict", QoS("reliable", "block", "DATA_HIGH")),
    Stream("sensor/stream", r"sensor/stream", ("stream_start", "stream_end"), "nondecreasing",
           QoS("reliable", "block", "DATA_HIGH", latest=True)),
    Stream("attitude", r"attitude", ("attitude",), "strict", QoS("reliable", "block", "DATA_HIGH", latest=True)),
    Stream("nav/solution", r"nav/solution", ("nav_solution",), "strict",
           QoS("reliable", "block", "DATA_HIGH", express=True, latest=True)),
    Stream("nav/aid", r"nav/aid/[^/]+", ("aid_report",), "nondecreasing", QoS("reliable", "block", "DATA")),
    Stream("nav/status", r"nav/status", ("nav_status",), "nondecreasing",
           QoS("reliable", "drop", "DATA", latest=True)),
    Stream("learn/samples", r"learn/samples", ("learn_sample",), "nondecreasing", QoS("reliable", "block", "DATA_LOW")),
    Stream("learn/query", r"learn/query", ("learn_query",), "nondecreasing",
           QoS("reliable", "block", "INTERACTIVE_HIGH", express=True)),
    Stream("learn/model", r"learn/model/[^/]+", ("model_params",), "none", QoS("reliable", "block", "DATA", latest=True)),
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


# ---------------------------------------------------------------------------------------------- schemas
# Field specs: "int", "float", "str", "bool", "map", "any", ("vec", n) float list of length n, ("floats",)
# float list of any length, ("ints",) int list of any length, ("opt", spec) None allowed. Header fields are
# common to every schema.
INT, FLOAT, STR, BOOL, MAP, ANY = "int", "float", "str", "bool", "map", "any"
FLOATS = ("floats",)
INTS = ("ints",)


def VEC(n: int) -> tuple:
    return ("vec", n)


def OPT(spec) -> tuple:
    return ("opt", spec)


HEADER = {"schema": STR, "v": INT, "t_ns": INT, "src": STR, "seq": INT, "pub_ns": INT}
SENSOR = {"cseq": INT}


@dataclass(frozen=True)
class Schema:
    name: str
    version: int
    fields: dict
    doc: str = ""


SCHEMAS: dict[str, Schema] = {}


def _schema(schema_name: str, schema_version: int, doc: str, /, **spec) -> None:
    SCHEMAS[schema_name] = Schema(schema_name, schema_version, {**HEADER, **spec}, doc)


_schema("imu", 1, "IMU increments over (t_prev, t_ns], body frame FRD: dtheta [rad], dvel [m/s]; dt_ns the interval.",
        **SENSOR, dt_ns=INT, dtheta=VEC(3), dvel=VEC(3))
_schema("imu_batch", 1, "N >= 1 consecutive IMU samples with cseq .. cseq+N-1 (see imu): t_ns_list, dt_ns_list (N "
        "ints, t_ns_list strictly increasing, its last = t_ns), dtheta, dvel (3N floats, sample after sample).",
        **SENSOR, t_ns_list=INTS, dt_ns_list=INTS, dtheta=FLOATS, dvel=FLOATS)
_schema("gnss", 1, "GNSS fix: llh [rad, rad, m], std_ned [m]; v_n/std_v_n [m/s] NED or None; fix: FixType; num_sats (-1 unknown).",
        **SENSOR, llh=VEC(3), std_ned=VEC(3), v_n=OPT(VEC(3)), std_v_n=OPT(VEC(3)), fix=INT, num_sats=INT)
_schema("stream_start", 1, "Start of a sensor stream: dataset name, NavConfig and InitialState (as maps, SI), "
        "expected counts per stream, GNSS outages withheld [[t0_ns, t1_ns], ...].",
        **SENSOR, dataset=STR, config=MAP, initial=MAP, counts=MAP, outages=ANY)
_schema("stream_end", 1, "End of a sensor stream: counts published per stream and the last cseq.",
        **SENSOR, counts=MAP, last_cseq=INT)
_schema("attitude", 1, "Attitude filter output: q_nb (scalar first), euler roll/pitch/yaw [rad], gyro_bias [rad/s], "
        "weight: accelerometer rejection weight in [0, 1]; omega_in_n [rad/s, NED] (optional, added compatibly): "
        "the earth + transport rate applied to this sample (zeros without an ins solution).",
        q_nb=VEC(4), euler=VEC(3), gyro_bias=VEC(3), weight=FLOAT, omega_in_n=OPT(VEC(3)))
_schema("nav_solution", 1, "Navigation solution of the IMU at t_ns (see zennav.nav.navigator.NavSolution); "
        "imu_cseq/imu_pub_ns identify the IMU sample that produced it (latency, loss checks).",
        llh=VEC(3), v_n=VEC(3), q_nb=VEC(4), euler=VEC(3), gyro_bias=VEC(3), accel_bias=VEC(3),
        std_pos_ned=VEC(3), std_v_n=VEC(3), std_euler=VEC(3), gnss_state=STR, imu_cseq=INT, imu_pub_ns=INT)
_schema("aid_report", 1, "One aiding update: observation, innovation, innovation variance (diagonal), "
        "test ratio (None when undefined), fused, reason when rejected.",
        source=STR, observation=FLOATS, innovation=FLOATS, innovation_var=FLOATS, test_ratio=OPT(FLOAT),
        fused=BOOL, reason=STR)
_schema("nav_status", 1, "ins health: GNSS state, core counters, rejected (bus validator reasons and samples dropped "
        "as not from the live stream), stream progress (src, done, last_cseq, merge counts), live model. "
        "Optional (added compatibly, checked strictly when present, see check_nav_status): alignment {state: "
        "coarse|fine|aligned, method, heading_std_rad, times_ns {state: t_ns}, tilt_source, gyrocompass}; "
        "adaptive_r: adaptive measurement noise on/off; measurement_noise {source: {R_diag [unit^2], ratio "
        "(R / reported R, diagonal) or None, branch, k, inflate, fading}}.",
        gnss_state=STR, counters=MAP, rejected=MAP, imu_count=INT, gnss_count=INT, stream=MAP, model=MAP,
        alignment=OPT(MAP), adaptive_r=OPT(BOOL), measurement_noise=OPT(MAP))
ALIGN_STATES = ("coarse", "fine", "aligned")
_schema("learn_sample", 1, "Training pair emitted while GNSS is valid: features and target (normalisation is the "
        "trainer's), variant names the target definition (zennav.nav.learning.TARGETS; target has OUTPUTS[variant] values).",
        features=FLOATS, target=FLOATS, variant=STR)
_schema("learn_query", 1, "Prediction request of the ins while GNSS is lost (zennav.nav.learning.LearnQuery): "
        "t_ns the query time, target the variant, features as in learn_sample, dt_s the interval of a rate target "
        "[s]. The query is identified by its header (src, seq); the answer is one correction naming them.",
        target=STR, features=FLOATS, dt_s=FLOAT)
_schema("model_params", 1, "Versioned parameter set: name, version, kind, created_t_ns, normalisation "
        "{key: {shape, data[, dtype]}} (or {key: floats}), arrays {key: {shape, data[, dtype]}}, metrics, checksum. "
        "format (optional) names the parameter-set format; with format 'zennav.paramset/2' (model_params_msg / "
        "paramset_of) the message is zennav.learn.paramset's set with each array's bytes as a number list, and "
        "checksum is paramset.checksum of that set, verified end to end; otherwise params_checksum.",
        name=STR, version=INT, kind=STR, created_t_ns=INT, norm=MAP, arrays=MAP, metrics=MAP, checksum=STR,
        format=OPT(STR))
_schema("correction", 1, "Predicted INS error: kind (the learn_query target, or e.g. 'pos_ned' [m]), value, 1-sigma "
        "std, model name and version used; t_ns the time of the query answered; query_src/query_seq (optional) "
        "the header of the learn_query answered.",
        kind=STR, value=FLOATS, std=FLOATS, model=STR, version=INT, query_src=OPT(STR), query_seq=OPT(INT))
_schema("service_status", 1, "Per-service heartbeat: state (starting|running|not_implemented|done|stopping), "
        "detail, counters, rejections per reason; t_ns is wall clock here.",
        service=STR, state=STR, detail=STR, counters=MAP, rejected=MAP)

SERVICE_STATES = ("starting", "running", "not_implemented", "done", "stopping", "error")


# ---------------------------------------------------------------------------------------------- codec
class ValidationError(ValueError):
    pass


def encode(msg: dict) -> bytes:
    """msgpack map -> bytes (float64 kept as float64, strings as str, bytes as bin)."""
    return msgpack.packb(msg, use_bin_type=True)


def decode(payload: bytes) -> Any:
    return msgpack.unpackb(payload, raw=False, strict_map_key=False)


def make(schema: str, t_ns: int, **fields) -> dict:
    """A message map with its schema/version and sample time; the bus adds src, seq and pub_ns."""
    s = SCHEMAS[schema]
    msg = {"schema": schema, "v": s.version, "t_ns": int(t_ns)}
    msg.update(fields)
    return msg


def floats(a) -> list:
    """Array-like -> list of Python floats (float64, exact)."""
    if type(a) is np.ndarray:
        return (a if a.dtype == np.float64 else a.astype(np.float64)).ravel().tolist()
    if type(a) in (list, tuple):
        return [float(x) for x in a]
    return np.asarray(a, dtype=np.float64).ravel().tolist()


def _pyval(v):
    if isinstance(v, np.ndarray):
        return [_pyval(x) for x in v.tolist()] if v.dtype.kind in "iub" else v.astype(np.float64).tolist()
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (np.floating,)):
        return float(v)
    if isinstance(v, (np.bool_,)):
        return bool(v)
    if is_dataclass(v):
        return dataclass_to_map(v)
    if isinstance(v, (list, tuple)):
        return [_pyval(x) for x in v]
    if isinstance(v, dict):
        return {str(k): _pyval(x) for k, x in v.items()}
    return v


def dataclass_to_map(obj) -> dict:
    """A (nested) dataclass -> msgpack-able map (arrays -> lists of float64)."""
    return {f.name: _pyval(getattr(obj, f.name)) for f in fields(obj)}


def map_to_dataclass(cls, m: dict):
    """Inverse of dataclass_to_map for NavConfig / InitialState / ImuNoise: lists -> float64 arrays,
    nested maps -> the field's dataclass; unknown keys are ignored."""
    kw = {}
    defaults = cls() if _has_all_defaults(cls) else None
    for f in fields(cls):
        if f.name not in m:
            continue
        v = m[f.name]
        cur = getattr(defaults, f.name) if defaults is not None else None
        if isinstance(v, dict) and is_dataclass(cur):
            v = map_to_dataclass(type(cur), v)
        elif isinstance(v, list):
            v = np.asarray(v, dtype=np.float64)
        kw[f.name] = v
    return cls(**kw)


def _has_all_defaults(cls) -> bool:
    from dataclasses import MISSING

    return all(f.default is not MISSING or f.default_factory is not MISSING for f in fields(cls))


# ---------------------------------------------------------------------------------------------- builders
def imu_msg(t_ns: int, dtheta, dvel, dt_ns: int, cseq: int) -> dict:
    return make("imu", t_ns, cseq=int(cseq), dt_ns=int(dt_ns), dtheta=floats(dtheta), dvel=floats(dvel))


def imu_batch_msg(t_ns: list, dt_ns: list, dtheta: list, dvel: list, cseq: int) -> dict:
    """imu_batch of N samples: t_ns, dt_ns (N ints), dtheta, dvel (N lists of 3 floats); cseq of the first."""
    return make("imu_batch", t_ns[-1], cseq=int(cseq), t_ns_list=list(t_ns), dt_ns_list=list(dt_ns),
                dtheta=[x for v in dtheta for x in v], dvel=[x for v in dvel for x in v])


def samples(msg: dict) -> list[dict]:
    """The sensor messages a (validated) sensor message stands for: an imu_batch's N imu messages (same header,
    cseq c .. c+N-1), any other message itself."""
    if msg["schema"] != "imu_batch":
        return [msg]
    th, dv, c = msg["dtheta"], msg["dvel"], msg["cseq"]
    head = {"src": msg["src"], "seq": msg["seq"], "pub_ns": msg["pub_ns"]}
    v = SCHEMAS["imu"].version
    return [{"schema": "imu", "v": v, "t_ns": t, "cseq": c + i, "dt_ns": d, "dtheta": th[3 * i:3 * i + 3],
             "dvel": dv[3 * i:3 * i + 3], **head}
            for i, (t, d) in enumerate(zip(msg["t_ns_list"], msg["dt_ns_list"]))]


def gnss_msg(fix, cseq: int) -> dict:
    """zennav.nav.types.GnssFix -> gnss message."""
    return make("gnss", fix.t_ns, cseq=int(cseq), llh=floats(fix.llh), std_ned=floats(fix.std_ned),
                v_n=None if fix.v_n is None else floats(fix.v_n),
                std_v_n=None if fix.std_v_n is None else floats(fix.std_v_n),
                fix=int(fix.fix), num_sats=int(fix.num_sats))


def gnss_fix(msg: dict):
    """gnss message -> zennav.nav.types.GnssFix."""
    from .nav.types import GnssFix

    v = msg.get("v_n")
    sv = msg.get("std_v_n")
    return GnssFix(t_ns=int(msg["t_ns"]), llh=np.array(msg["llh"]), std_ned=np.array(msg["std_ned"]),
                   v_n=None if v is None else np.array(v),
                   std_v_n=None if sv is None else np.array(sv),
                   fix=int(msg["fix"]), num_sats=int(msg["num_sats"]))


def nav_solution_msg(sol, imu_cseq: int = -1, imu_pub_ns: int = 0) -> dict:
    return make("nav_solution", sol.t_ns, llh=floats(sol.llh), v_n=floats(sol.v_n), q_nb=floats(sol.q_nb),
                euler=floats(sol.euler), gyro_bias=floats(sol.gyro_bias), accel_bias=floats(sol.accel_bias),
                std_pos_ned=floats(sol.std_pos_ned), std_v_n=floats(sol.std_v_n), std_euler=floats(sol.std_euler),
                gnss_state=str(sol.gnss_state), imu_cseq=int(imu_cseq), imu_pub_ns=int(imu_pub_ns))


def aid_report_msg(rep) -> dict:
    tr = float(rep.test_ratio)
    return make("aid_report", rep.t_ns, source=str(rep.source), observation=floats(rep.observation),
                innovation=floats(rep.innovation), innovation_var=floats(rep.innovation_var),
                test_ratio=tr if math.isfinite(tr) else None, fused=bool(rep.fused), reason=str(rep.reason))


def service_status_msg(service: str, state: str, detail: str = "", counters=None, rejected=None, t_ns=None) -> dict:
    import time

    return make("service_status", time.time_ns() if t_ns is None else t_ns, service=service, state=state,
                detail=detail, counters=_pyval(dict(counters or {})), rejected=_pyval(dict(rejected or {})))


def params_checksum(msg: dict) -> str:
    """sha256 over the canonical msgpack of (name, version, kind, norm, arrays): trainer and predictor agree on it."""
    canon = encode([msg.get("name"), msg.get("version"), msg.get("kind"), _sorted(msg.get("norm")),
                    _sorted(msg.get("arrays"))])
    return "sha256:" + hashlib.sha256(canon).hexdigest()


def _sorted(v):
    if isinstance(v, dict):
        return [[k, _sorted(v[k])] for k in sorted(v)]
    if isinstance(v, list):
        return [_sorted(x) for x in v]
    return v


def array_map(a) -> dict:
    """numpy array -> {"shape": [...], "data": [float64...]} for model_params.arrays."""
    a = np.asarray(a, dtype=np.float64)
    return {"shape": list(a.shape), "data": a.ravel().tolist()}


def map_array(m: dict) -> np.ndarray:
    return np.asarray(m["data"], dtype=np.float64).reshape(m["shape"])


# learning loop (DESIGN.md section 5): ins -> learn/samples -> trainer -> learn/model/<name> -> predictor;
# ins -> learn/query -> predictor -> learn/correction -> ins
PARAMSET_FORMAT = "zennav.paramset/2"  # zennav.learn.paramset.SCHEMA (not imported: no learn dependency here)
_PS_DTYPES = ("<f8", "<i8")  # little-endian float64, int64


def learn_sample_msg(sample) -> dict:
    """zennav.nav.learning.LearnSample -> learn_sample message."""
    return make("learn_sample", sample.t_ns, features=floats(sample.features), target=floats(sample.value),
                variant=str(sample.target))


def learn_query_msg(query) -> dict:
    """zennav.nav.learning.LearnQuery -> learn_query message."""
    return make("learn_query", query.t_ns, target=str(query.target), features=floats(query.features),
                dt_s=float(query.dt_s))


def correction_msg(query: dict, value, std, model: str, version: int) -> dict:
    """The answer to a (published, so src/seq-stamped) learn_query message."""
    return make("correction", query["t_ns"], kind=query["target"], value=floats(value), std=floats(std),
                model=str(model), version=int(version), query_src=query["src"], query_seq=int(query["seq"]))


def model_params_msg(ps: dict) -> dict:
    """A parameter set of zennav.learn.paramset (build()) -> model_params message: the same fields, each array's
    little-endian bytes as a number list (float64 -> float, int64 -> int: exact), the set's own checksum.
    paramset_of() is the inverse, byte for byte, so the predictor verifies the trainer's checksum."""
    def wire(enc: dict) -> dict:
        if enc["dtype"] not in _PS_DTYPES:
            raise ValueError(f"unsupported dtype {enc['dtype']!r}")
        return {"dtype": enc["dtype"], "shape": [int(d) for d in enc["shape"]],
                "data": np.frombuffer(enc["data"], dtype=np.dtype(enc["dtype"])).tolist()}

    return make("model_params", ps["created_t_ns"], name=ps["name"], version=int(ps["version"]), kind=ps["kind"],
                created_t_ns=int(ps["created_t_ns"]), norm={k: wire(v) for k, v in ps["norm"].items()},
                arrays={k: wire(v) for k, v in ps["arrays"].items()}, metrics=_pyval(dict(ps["metrics"])),
                checksum=ps["checksum"], format=PARAMSET_FORMAT if ps.get("schema") == PARAMSET_FORMAT
                else str(ps.get("schema")))


def paramset_of(msg: dict) -> dict:
    """model_params message -> the zennav.learn.paramset message it carries (for paramset.validate, which then
    checks schema, checksum, shapes, finiteness and version). An array map that is not convertible is passed on
    as it is, so that validate rejects it with reason 'schema'; a float in an int64 array likewise."""
    def raw(m):
        if not (isinstance(m, dict) and {"dtype", "shape", "data"} <= set(m) and isinstance(m["data"], list)):
            return m
        if m["dtype"] not in _PS_DTYPES or (m["dtype"] == "<i8" and not all(type(x) is int for x in m["data"])):
            return m
        try:
            data = np.asarray(m["data"], dtype=np.dtype(m["dtype"])).tobytes()
        except (TypeError, ValueError, OverflowError):
            return m
        return {"dtype": m["dtype"], "shape": m["shape"], "data": data}

    return {"schema": msg.get("format"), "kind": msg["kind"], "name": msg["name"], "version": msg["version"],
            "created_t_ns": msg["created_t_ns"], "norm": {k: raw(v) for k, v in msg["norm"].items()},
            "arrays": {k: raw(v) for k, v in msg["arrays"].items()}, "metrics": msg["metrics"],
            "checksum": msg["checksum"]}


# ---------------------------------------------------------------------------------------------- validation
def _check_value(spec, v, name: str) -> str:
    """'' when v fits spec, else 'code: detail'. Float lists are normalised in place by the caller."""
    if isinstance(spec, tuple):
        kind = spec[0]
        if kind == "opt":
            return "" if v is None else _check_value(spec[1], v, name)
        if kind == "ints":
            if not isinstance(v, list):
                return f"bad_type: {name} is {type(v).__name__}, want list"
            bad = next((i for i, x in enumerate(v) if type(x) is not int), None)
            return "" if bad is None else f"bad_type: {name}[{bad}] is {type(v[bad]).__name__}, want int"
        if kind in ("vec", "floats"):
            if not isinstance(v, list):
                return f"bad_type: {name} is {type(v).__name__}, want list"
            if kind == "vec" and len(v) != spec[1]:
                return f"bad_shape: {name} has {len(v)} elements, want {spec[1]}"
            if all(type(x) is float for x in v) and all(map(math.isfinite, v)):
                return ""
            for i, x in enumerate(v):
                tx = type(x)
                if tx is float:
                    if not math.isfinite(x):
                        return f"not_finite: {name}[{i}]"
                elif tx is not int:
                    return f"bad_type: {name}[{i}] is {tx.__name__}"
            return ""
        raise AssertionError(spec)
    t = type(v)
    if spec == INT:
        return "" if t is int else f"bad_type: {name} is {t.__name__}, want int"
    if spec == FLOAT:
        if t is float:
            return "" if math.isfinite(v) else f"not_finite: {name}"
        return "" if t is int else f"bad_type: {name} is {t.__name__}, want float"
    if spec == STR:
        return "" if t is str else f"bad_type: {name} is {t.__name__}, want str"
    if spec == BOOL:
        return "" if t is bool else f"bad_type: {name} is {t.__name__}, want bool"
    if spec == MAP:
        if t is not dict:
            return f"bad_type: {name} is {t.__name__}, want map"
        return _check_finite_deep(v, name)
    if spec == ANY:
        return _check_finite_deep(v, name)
    raise AssertionError(spec)


def _check_finite_deep(v, name: str, depth: int = 0) -> str:
    if depth > 16:
        return f"bad_shape: {name} nested too deep"
    t = type(v)
    if t is float:
        return "" if math.isfinite(v) else f"not_finite: {name}"
    if t is dict:
        for k, x in v.items():
            r = _check_finite_deep(x, f"{name}.{k}", depth + 1)
            if r:
                return r
    elif t is list:
        for i, x in enumerate(v):
            if type(x) is float:
                if not math.isfinite(x):
                    return f"not_finite: {name}[{i}]"
            elif type(x) in (dict, list):
                r = _check_finite_deep(x, f"{name}[{i}]", depth + 1)
                if r:
                    return r
    return ""


def _normalise(schema: Schema, msg: dict) -> None:
    """ints inside float fields -> float (so consumers see float64 throughout)."""
    for name, spec in schema.fields.items():
        if isinstance(spec, tuple):
            inner = spec[1] if spec[0] == "opt" else spec
            v = msg.get(name)
            if v is None:
                continue
            if isinstance(inner, tuple) and inner[0] in ("vec", "floats"):
                if any(type(x) is int for x in v):
                    msg[name] = [float(x) for x in v]
            elif inner == FLOAT and type(v) is int:
                msg[name] = float(v)
        elif spec == FLOAT and type(msg.get(name)) is int:
            msg[name] = float(msg[name])


def validate_map(msg: Any, key: str | None = None) -> str:
    """Static checks of a decoded message (no time state): '' or 'code: detail'."""
    if not isinstance(msg, dict):
        return f"not_a_map: {type(msg).__name__}"
    name = msg.get("schema")
    if not isinstance(name, str):
        return "missing_field: schema"
    schema = SCHEMAS.get(name)
    if schema is None:
        return f"unknown_schema: {name[:40]!r}"
    if key is not None:
        stream = stream_of(key)
        if stream is None:
            return f"unknown_key: {key}"
        if name not in stream.schemas:
            return f"wrong_schema: {name} on {stream.name}"
    v = msg.get("v")
    if v != schema.version or type(v) is not int:
        return f"unsupported_version: {name} v{v!r}, want v{schema.version}"
    fast = _FAST.get(name)
    if fast is None:
        fast = _FAST[name] = _compile_fast(schema)
    if fast(msg):  # straight-line check of every field; the loop below explains failures
        if name == "imu_batch":
            return check_imu_batch(msg)
        if name not in ("model_params", "nav_status"):
            return ""
    needs_norm = False
    isfinite = math.isfinite
    for fname, spec, code, n, optional in _plan(schema):
        val = msg.get(fname, _MISSING)
        if val is _MISSING or (val is None and optional):
            if optional:
                continue
            return f"missing_field: {name}.{fname}"
        if code == 1:  # int (bool is not an int here)
            if type(val) is not int:
                return f"bad_type: {fname} is {type(val).__name__}, want int"
            continue
        if code == 2 and type(val) is list and (n == 0 or len(val) == n) \
                and all(type(x) is float for x in val) and all(map(isfinite, val)):
            continue  # fast path: a float list of the right length, all finite
        if code == 3 and type(val) is str:
            continue
        r = _check_value(spec, val, fname)
        if r:
            return r
        needs_norm = needs_norm or code in (2, 4)
    if name == "model_params":
        for an, am in msg["arrays"].items():
            if not (isinstance(am, dict) and isinstance(am.get("shape"), list) and isinstance(am.get("data"), list)
                    and all(type(d) is int and d >= 0 for d in am["shape"])):
                return f"bad_shape: arrays.{an} needs shape and data"
            if math.prod(am["shape"]) != len(am["data"]):
                return f"bad_shape: arrays.{an} shape {am['shape']} vs {len(am['data'])} values"
            if not all(type(x) in (float, int) for x in am["data"]):
                return f"bad_type: arrays.{an} data not numbers"
    if name == "nav_status":
        r = check_nav_status(msg)
        if r:
            return r
    if name == "imu_batch":
        r = check_imu_batch(msg)
        if r:
            return r
    if needs_norm:
        _normalise(schema, msg)
    return ""


def check_imu_batch(msg: dict) -> str:
    """Consistency of an imu_batch (types already checked): '' or 'code: detail'."""
    t, n = msg["t_ns_list"], len(msg["t_ns_list"])
    if n == 0 or len(msg["dt_ns_list"]) != n or len(msg["dtheta"]) != 3 * n or len(msg["dvel"]) != 3 * n:
        return (f"bad_shape: imu_batch of {n} times needs {n} dt_ns and 3x{n} dtheta/dvel, got "
                f"{len(msg['dt_ns_list'])}, {len(msg['dtheta'])}, {len(msg['dvel'])}")
    if t[-1] != msg["t_ns"] or any(b <= a for a, b in zip(t, t[1:])):
        return "bad_value: imu_batch t_ns_list must increase strictly and end at t_ns"
    return ""


def _num(x) -> bool:
    return type(x) is float or type(x) is int


def check_nav_status(msg: dict) -> str:
    """Structure of nav_status's optional maps (values are already known finite): '' or 'code: detail'.
    Extra keys inside them are tolerated (forward compatible), the documented ones must have their types."""
    al = msg.get("alignment")
    if al is not None:
        if al.get("state") not in ALIGN_STATES:
            return f"bad_value: alignment.state {str(al.get('state'))[:40]!r} not in {ALIGN_STATES}"
        for f in ("method", "tilt_source", "gyrocompass"):
            if type(al.get(f)) is not str:
                return f"bad_type: alignment.{f} is {type(al.get(f)).__name__}, want str"
        hs = al.get("heading_std_rad")
        if not _num(hs) or hs < 0:
            return "bad_value: alignment.heading_std_rad must be a number >= 0"
        times = al.get("times_ns")
        if type(times) is not dict or not all(k in ALIGN_STATES and type(v) is int for k, v in times.items()):
            return "bad_value: alignment.times_ns must map alignment states to int t_ns"
    mn = msg.get("measurement_noise")
    if mn is not None:
        for src, e in mn.items():
            if type(src) is not str or not _CHUNK.match(src):
                return f"bad_value: measurement_noise source {str(src)[:40]!r}"
            if type(e) is not dict:
                return f"bad_type: measurement_noise.{src} is {type(e).__name__}, want map"
            rd = e.get("R_diag")
            if type(rd) is not list or not 1 <= len(rd) <= 6 or not all(_num(x) and x >= 0 for x in rd):
                return f"bad_value: measurement_noise.{src}.R_diag must be 1..6 numbers >= 0"
            ratio = e.get("ratio")
            if ratio is not None and (type(ratio) is not list or len(ratio) != len(rd)
                                      or not all(_num(x) and x > 0 for x in ratio)):
                return f"bad_value: measurement_noise.{src}.ratio must be None or {len(rd)} numbers > 0"
            if type(e.get("branch")) is not str:
                return f"bad_type: measurement_noise.{src}.branch must be str"
            for f in ("k", "inflate", "fading"):
                if f in e and type(e[f]) is not int:
                    return f"bad_type: measurement_noise.{src}.{f} must be int"
    return ""


_MISSING = object()
_PLANS: dict[str, list] = {}
_FAST: dict[str, Callable[[dict], bool]] = {}


def _compile_fast(schema: Schema) -> Callable[[dict], bool]:
    """A generated function that returns True when every field of ``schema`` is present with the exact type
    (floats as Python floats, finite) -- the common case, checked without loops or dispatch. False means
    "use the generic checker", which finds the reason (or accepts and normalises ints in float fields)."""
    lines = ["def fast(msg):", "    g = msg.get"]
    for i, (fname, spec) in enumerate(schema.fields.items()):
        optional = isinstance(spec, tuple) and spec[0] == "opt"
        inner = spec[1] if optional else spec
        v = f"v{i}"
        lines.append(f"    {v} = g({fname!r}, MISSING)")
        if inner == INT:
            cond = f"type({v}) is int"
        elif inner == FLOAT:
            cond = f"type({v}) is float and isfinite({v})"
        elif inner == STR:
            cond = f"type({v}) is str"
        elif inner == BOOL:
            cond = f"type({v}) is bool"
        elif isinstance(inner, tuple) and inner[0] == "vec" and inner[1] <= 8:
            n = inner[1]
            elems = " and ".join(f"type({v}[{j}]) is float and isfinite({v}[{j}])" for j in range(n))
            cond = f"type({v}) is list and len({v}) == {n}" + (f" and {elems}" if n else "")
        elif inner == INTS:
            cond = f"type({v}) is list and all(type(x) is int for x in {v})"
        elif isinstance(inner, tuple) and inner[0] in ("vec", "floats"):
            ln = f" and len({v}) == {inner[1]}" if inner[0] == "vec" else ""
            cond = f"type({v}) is list{ln} and all(type(x) is float for x in {v}) and all(map(isfinite, {v}))"
        elif inner == MAP:
            cond = f"type({v}) is dict and not deep({v}, '')"
        else:
            cond = f"{v} is not MISSING and not deep({v}, '')"
        if optional:
            cond = f"{v} is MISSING or {v} is None or ({cond})"
        lines.append(f"    if not ({cond}): return False")
    lines.append("    return True")
    ns = {"MISSING": _MISSING, "isfinite": math.isfinite, "deep": _check_finite_deep}
    exec("\n".join(lines), ns)  # noqa: S102 (source built from this module's own schema table)
    return ns["fast"]


def _plan(schema: Schema) -> list:
    """Per-field check plan: (name, spec, code, n, optional); code 1 int, 2 float list, 3 str, 4 float, 0 other."""
    plan = _PLANS.get(schema.name)
    if plan is None:
        plan = []
        for fname, spec in schema.fields.items():
            optional = isinstance(spec, tuple) and spec[0] == "opt"
            inner = spec[1] if optional else spec
            if inner == INT:
                code, n = 1, 0
            elif isinstance(inner, tuple) and inner[0] in ("vec", "floats"):
                code, n = 2, (inner[1] if inner[0] == "vec" else 0)
            elif inner == STR:
                code, n = 3, 0
            elif inner == FLOAT:
                code, n = 4, 0
            else:
                code, n = 0, 0
            plan.append((fname, spec, code, n, optional))
        _PLANS[schema.name] = plan
    return plan


class Validator:
    """Decodes and validates messages of one subscriber; keeps the last t_ns per (key, src) for the
    monotonic-time check and counts rejections per reason code. Not thread-safe (one per consumer thread)."""

    def __init__(self):
        self.last_t: dict[tuple[str, str], int] = {}
        self.rejected: Counter[str] = Counter()
        self.rejected_by_key: Counter[tuple[str, str]] = Counter()
        self.accepted = 0

    def check(self, key: str, payload: bytes | bytearray | memoryview) -> tuple[dict | None, str]:
        try:
            msg = decode(bytes(payload))
        except Exception as e:  # random bytes: msgpack raises many types
            return self._reject(key, f"decode_error: {type(e).__name__}")
        r = validate_map(msg, key)
        if r:
            return self._reject(key, r)
        policy = stream_of(key).time
        if policy != "none":
            sk = (key, msg["src"])
            last = self.last_t.get(sk)
            t = msg["t_ns"]
            first = msg["t_ns_list"][0] if msg["schema"] == "imu_batch" else t
            if last is not None and (first < last or (policy == "strict" and first == last)):
                return self._reject(key, f"time_backwards: t_ns {first} after {last} on {key}")
            self.last_t[sk] = t
        self.accepted += 1
        return msg, ""

    def _reject(self, key: str, reason: str) -> tuple[None, str]:
        code = reason.split(":", 1)[0]
        self.rejected[code] += 1
        self.rejected_by_key[(key, code)] += 1
        return None, reason

    def forget(self, src: str) -> None:
        """Drop the time state of one source (e.g. when a stream restarts)."""
        for k in [k for k in self.last_t if k[1] == src]:
            del self.last_t[k]


# ---------------------------------------------------------------------------------------------- ordering
@dataclass(order=True)
class _Held:
    cseq: int
    n: int
    item: Any = field(compare=False)


class SequenceMerger:
    """Releases items strictly in ``cseq`` order (see the module docstring): early ones are held; duplicates
    (cseq already released or already held) are dropped and counted; when more than ``max_hold`` items wait
    for a missing cseq, the gap is skipped and counted. ``flush()`` releases everything held (stream end)."""

    def __init__(self, next_cseq: int = 0, max_hold: int = 100_000):
        self.next = next_cseq
        self.max_hold = max_hold
        self._heap: list[_Held] = []
        self._held: set[int] = set()
        self._n = 0
        self.counts: Counter[str] = Counter()

    def push(self, cseq: int, item, emit: Callable[[Any], None]) -> None:
        if cseq < self.next or cseq in self._held:
            self.counts["duplicate"] += 1
            return
        if cseq == self.next and not self._heap:
            self.next += 1
            emit(item)
            return
        self.counts["reordered"] += 1
        self._n += 1
        heapq.heappush(self._heap, _Held(cseq, self._n, item))
        self._held.add(cseq)
        self._drain(emit)
        if len(self._heap) > self.max_hold:
            self._skip_gap(emit)

    def _drain(self, emit) -> None:
        h = self._heap
        while h and h[0].cseq == self.next:
            it = heapq.heappop(h)
            self._held.discard(it.cseq)
            self.next += 1
            emit(it.item)

    def _skip_gap(self, emit) -> None:
        first = self._heap[0].cseq
        self.counts["gap"] += first - self.next
        self.next = first
        self._drain(emit)

    def flush(self, emit) -> None:
        while self._heap:
            self._skip_gap(emit)

    @property
    def held(self) -> int:
        return len(self._heap)
