"""Navigation messages (ins and attitude outputs): attitude, nav_solution (and nav_solution_batch, the solutions
of consecutive IMU samples in one message), aid_report (one aid source's status record, on ``nav/aid/<source>``)
and nav_status, with their builders."""
from __future__ import annotations

import math
import struct

import msgpack
import numpy as np

from .codec import floats, make
from .keys import CHUNK
from .schema import BOOL, FLOAT, FLOATS, INT, INTS, MAP, OPT, SCHEMAS, STR, STRS, VEC, define

ALIGN_STATES = ("coarse", "fine", "aligned")


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
        for f in ("initial_state", "waiting"):
            if type(al.get(f, "")) is not str:
                return f"bad_type: alignment.{f} is {type(al.get(f)).__name__}, want str"
        hs = al.get("heading_std_rad")
        if not _num(hs) or hs < 0:
            return "bad_value: alignment.heading_std_rad must be a number >= 0"
        times = al.get("times_ns")
        if type(times) is not dict or not all(k in ALIGN_STATES and type(v) is int for k, v in times.items()):
            return "bad_value: alignment.times_ns must map alignment states to int t_ns"
    ac = msg.get("aid_counts")
    if ac is not None and not all(type(k) is str and type(n) is int and n >= 0 for k, n in ac.items()):
        return "bad_value: aid_counts must map stream names to int counts >= 0"
    mn = msg.get("measurement_noise")
    if mn is not None:
        for src, e in mn.items():
            if type(src) is not str or not CHUNK.match(src):
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


define("attitude", 1, "Attitude filter output: q_nb (scalar first), euler roll/pitch/yaw [rad], gyro_bias [rad/s], "
       "weight: accelerometer rejection weight in [0, 1]; omega_in_n [rad/s, NED] (optional, added compatibly): "
       "the earth + transport rate applied to this sample (zeros without an ins solution); accel_b [m/s^2], "
       "vel_b [m/s] (optional, added compatibly; None without a velocity source): the vehicle's acceleration and "
       "velocity in body axes applied to this sample (zeros when the velocity was stale or not there yet).",
       q_nb=VEC(4), euler=VEC(3), gyro_bias=VEC(3), weight=FLOAT, omega_in_n=OPT(VEC(3)), accel_b=OPT(VEC(3)),
       vel_b=OPT(VEC(3)))
define("nav_solution", 1, "Navigation solution of the IMU at t_ns (see zennav.nav.navigator.NavSolution); "
       "imu_cseq/imu_pub_ns identify the IMU sample that produced it (latency, loss checks).",
       llh=VEC(3), v_n=VEC(3), q_nb=VEC(4), euler=VEC(3), gyro_bias=VEC(3), accel_bias=VEC(3),
       std_pos_ned=VEC(3), std_v_n=VEC(3), std_euler=VEC(3), gnss_state=STR, imu_cseq=INT, imu_pub_ns=INT)
def check_nav_solution_batch(msg: dict) -> str:
    """Consistency of a nav_solution_batch (types already checked): '' or 'code: detail'."""
    t, n = msg["t_ns_list"], len(msg["t_ns_list"])
    want = {f: k * n for f, k in _BATCH_ROWS}
    if n == 0 or len(msg["imu_cseq"]) != n or len(msg["imu_pub_ns"]) != n or \
            any(len(msg[f]) != k for f, k in want.items()):
        return f"bad_shape: nav_solution_batch of {n} times needs {n} imu_cseq/imu_pub_ns and rows of " + \
            ", ".join(f"{f} {k}" for f, k in want.items())
    if t[-1] != msg["t_ns"] or any(b <= a for a, b in zip(t, t[1:])):
        return "bad_value: nav_solution_batch t_ns_list must increase strictly and end at t_ns"
    return ""


_BATCH_ROWS = (("llh", 3), ("v_n", 3), ("q_nb", 4), ("std_pos_ned", 3), ("std_v_n", 3), ("std_euler", 3))
define("nav_solution_batch", 1, "The nav_solution of each of N >= 1 consecutive IMU samples in one message (the ins "
       "with --solution-batch: one per stretch of an imu_batch its block loop ran at once): t_ns_list, imu_cseq, "
       "imu_pub_ns (N ints, t_ns_list strictly increasing, its last = t_ns); llh, v_n, q_nb, std_pos_ned, std_v_n, "
       "std_euler (N rows each, row after row); gyro_bias, accel_bias, gnss_state: the same for every row. Row i is "
       "the nav_solution at t_ns_list[i] with euler = zennav.messages.euler_list(q_nb of row i); subscribers of "
       "zennav.bus get the N nav_solution messages (``solutions``).",
       check=check_nav_solution_batch, t_ns_list=INTS, imu_cseq=INTS, imu_pub_ns=INTS, llh=FLOATS, v_n=FLOATS,
       q_nb=FLOATS, std_pos_ned=FLOATS, std_v_n=FLOATS, std_euler=FLOATS, gyro_bias=VEC(3), accel_bias=VEC(3),
       gnss_state=STR)
define("aid_report", 1, "One aid source's status record: observation, innovation, innovation variance (diagonal), "
       "test ratio (None when undefined), fused, reason when rejected; optional (added compatibly): "
       "last_fused_t_ns the time this source last fused [ns GPS], faults the source's fault flags.",
       source=STR, observation=FLOATS, innovation=FLOATS, innovation_var=FLOATS, test_ratio=OPT(FLOAT),
       fused=BOOL, reason=STR, last_fused_t_ns=OPT(INT), faults=OPT(STRS))
define("nav_status", 1, "ins health: GNSS state, core counters, rejected (bus validator reasons and samples dropped "
       "as not from the live stream), stream progress (src, done, last_cseq, merge counts), live model. "
       "Optional (added compatibly, checked strictly when present, see check_nav_status): alignment {state: "
       "coarse|fine|aligned, method, heading_std_rad, times_ns {state: t_ns}, tilt_source, gyrocompass, optional "
       "initial_state: the configured initial state's test against the first fixes ('', at rest, position and "
       "velocity reset, accepted, rejected: why), optional waiting: while coarse, what the alignment waits for}; "
       "adaptive_r: adaptive measurement noise on/off; measurement_noise {source: {R_diag [unit^2], ratio "
       "(R / reported R, diagonal) or None, branch, k, inflate, fading}}; aid_counts {stream: samples consumed} "
       "of the aid streams (dvl, depth) the stream has.",
       check=check_nav_status, gnss_state=STR, counters=MAP, rejected=MAP, imu_count=INT, gnss_count=INT,
       stream=MAP, model=MAP, alignment=OPT(MAP), adaptive_r=OPT(BOOL), measurement_noise=OPT(MAP),
       aid_counts=OPT(MAP))


def nav_solution_msg(sol, imu_cseq: int = -1, imu_pub_ns: int = 0) -> dict:
    """zennav.nav.navigator.NavSolution -> nav_solution message."""
    return make("nav_solution", sol.t_ns, llh=floats(sol.llh), v_n=floats(sol.v_n), q_nb=floats(sol.q_nb),
                euler=floats(sol.euler), gyro_bias=floats(sol.gyro_bias), accel_bias=floats(sol.accel_bias),
                std_pos_ned=floats(sol.std_pos_ned), std_v_n=floats(sol.std_v_n), std_euler=floats(sol.std_euler),
                gnss_state=str(sol.gnss_state), imu_cseq=int(imu_cseq), imu_pub_ns=int(imu_pub_ns))


def aid_report_msg(rep) -> dict:
    """An aid source's status record (zennav.nav AidReport) -> aid_report message; last_fused_t_ns and faults
    are copied when the record has them."""
    tr = float(rep.test_ratio)
    msg = make("aid_report", rep.t_ns, source=str(rep.source), observation=floats(rep.observation),
               innovation=floats(rep.innovation), innovation_var=floats(rep.innovation_var),
               test_ratio=tr if math.isfinite(tr) else None, fused=bool(rep.fused), reason=str(rep.reason))
    last = getattr(rep, "last_fused_t_ns", None)
    if last is not None:
        msg["last_fused_t_ns"] = int(last)
    faults = getattr(rep, "faults", None)
    if faults is not None:
        msg["faults"] = [str(f) for f in faults]
    return msg


def euler_list(q0: float, q1: float, q2: float, q3: float) -> list:
    """(roll, pitch, yaw) [rad] of q_nb (scalar first): the same float operations as
    zennav.nav.rotation.quat_to_euler, without numpy (hot path: one call per IMU sample)."""
    c20 = 2 * (q1 * q3 - q0 * q2)
    c21 = 2 * (q2 * q3 + q0 * q1)
    c22 = q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3
    c10 = 2 * (q1 * q2 + q0 * q3)
    c00 = q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3
    return [math.atan2(c21, c22), math.atan2(-c20, math.hypot(c21, c22)), math.atan2(c10, c00)]


_LIST_CACHE: dict[int, tuple] = {}


def _as_list(a) -> list:
    """floats(a), cached by object identity: the engine replaces (never mutates) its bias lists and std arrays
    when they change, so most samples reuse the previous conversion."""
    hit = _LIST_CACHE.get(id(a))
    if hit is not None and hit[0] is a:
        return hit[1]
    out = floats(a)
    if len(_LIST_CACHE) > 64:
        _LIST_CACHE.clear()
    _LIST_CACHE[id(a)] = (a, out)
    return out


def nav_solution_msg_of(nav, imu_cseq: int = -1, imu_pub_ns: int = 0) -> dict:
    """nav_solution of a Navigator's current state, the fast path of the ins's hot loop (>= 20 kHz): reads the
    state's floats directly (the same values as ``nav_solution_msg(nav.solution())``,
    tests/unit/test_messages.py checks it)."""
    s = nav.state
    return nav_solution_msg_of_row(nav, nav.t_ns, (s.lat, s.lon, s.h, s.vn, s.ve, s.vd, s.q0, s.q1, s.q2, s.q3),
                                   _as_list(nav.std_pos_ned), _as_list(nav.std_v_n), _as_list(nav.std_att),
                                   imu_cseq, imu_pub_ns)


def nav_solution_msg_of_row(nav, t_ns: int, row, std_pos_ned: list, std_v_n: list, std_euler: list,
                            imu_cseq: int, imu_pub_ns: int) -> dict:
    """nav_solution at t_ns [ns] of the navigation state row (lat, lon [rad], h [m], v_n [m/s, NED], q_nb: 10
    floats, a row of the engine's block loop Navigator.run_imu) with its 1-sigma [m, m/s, rad] and the Navigator's
    biases and GNSS state (constant over a block)."""
    lat, lon, h, vn, ve, vd, q0, q1, q2, q3 = row
    return make("nav_solution", t_ns, llh=[lat, lon, h], v_n=[vn, ve, vd], q_nb=[q0, q1, q2, q3],
                euler=euler_list(q0, q1, q2, q3), gyro_bias=_as_list(nav.gyro_bias),
                accel_bias=_as_list(nav.accel_bias), std_pos_ned=std_pos_ned, std_v_n=std_v_n, std_euler=std_euler,
                gnss_state=str(nav.gnss_state), imu_cseq=int(imu_cseq), imu_pub_ns=int(imu_pub_ns))


def nav_solution_batch_msg(nav, t_ns: list, rows: np.ndarray, std: np.ndarray, imu_cseq: list,
                           imu_pub_ns: list) -> dict:
    """nav_solution_batch of the solutions at t_ns (N ints [ns]) with rows (N, 10: lat, lon [rad], h [m], v_n [m/s,
    NED], q_nb; rows of the engine's block loop Navigator.run_imu) and std (N, 9: the 1-sigma of position [m, NED],
    velocity [m/s, NED], attitude [rad]), with the Navigator's biases and GNSS state (constant over a block)."""
    return make("nav_solution_batch", int(t_ns[-1]), t_ns_list=[int(x) for x in t_ns],
                imu_cseq=[int(x) for x in imu_cseq], imu_pub_ns=[int(x) for x in imu_pub_ns],
                llh=rows[:, 0:3].ravel().tolist(), v_n=rows[:, 3:6].ravel().tolist(),
                q_nb=rows[:, 6:10].ravel().tolist(), std_pos_ned=std[:, 0:3].ravel().tolist(),
                std_v_n=std[:, 3:6].ravel().tolist(), std_euler=std[:, 6:9].ravel().tolist(),
                gyro_bias=_as_list(nav.gyro_bias), accel_bias=_as_list(nav.accel_bias),
                gnss_state=str(nav.gnss_state))


def solutions(msg: dict) -> list[dict]:
    """The nav_solution messages a (validated) nav_solution_batch stands for, each with the batch's header (src,
    seq, pub_ns): exactly the maps the ins publishes one by one without --solution-batch; any other message
    itself."""
    if msg["schema"] != "nav_solution_batch":
        return [msg]
    head = {"src": msg["src"], "seq": msg["seq"], "pub_ns": msg["pub_ns"]}
    v = SCHEMAS["nav_solution"].version
    llh, v_n, q, sp, sv, se = (msg[f] for f, _ in _BATCH_ROWS)
    gb, ab, state = msg["gyro_bias"], msg["accel_bias"], msg["gnss_state"]
    out = []
    for i, (t, c, p) in enumerate(zip(msg["t_ns_list"], msg["imu_cseq"], msg["imu_pub_ns"])):
        a, b = 3 * i, 3 * i + 3
        q_nb = q[4 * i:4 * i + 4]
        out.append({"schema": "nav_solution", "v": v, "t_ns": t, "llh": llh[a:b], "v_n": v_n[a:b], "q_nb": q_nb,
                    "euler": euler_list(*q_nb), "gyro_bias": list(gb), "accel_bias": list(ab),
                    "std_pos_ned": sp[a:b], "std_v_n": sv[a:b], "std_euler": se[a:b], "gnss_state": state,
                    "imu_cseq": c, "imu_pub_ns": p, **head})
    return out


_U8, _U16, _U32, _U64 = (struct.Struct(f">B{c}").pack for c in "BHIQ")
_I8, _I16, _I32, _I64 = (struct.Struct(f">B{c}").pack for c in "bhiq")


def _int(n: int) -> bytes:
    """msgpack's encoding of the int n (the smallest of its formats, as msgpack.Packer chooses)."""
    if n >= 0x100000000:  # the common case first: times in ns
        return _U64(0xcf, n)
    if n >= 0:
        if n < 0x80:
            return bytes((n,))
        if n < 0x100:
            return _U8(0xcc, n)
        if n < 0x10000:
            return _U16(0xcd, n)
        return _U32(0xce, n)
    if n >= -32:
        return bytes((n & 0xff,))
    if n >= -0x80:
        return _I8(0xd0, n)
    if n >= -0x8000:
        return _I16(0xd1, n)
    return _I32(0xd2, n) if n >= -0x80000000 else _I64(0xd3, n)


class SolutionPacker:
    """nav_solution messages packed straight into msgpack bytes: ``pack(...)`` returns exactly ``encode`` of the map
    that nav_solution_msg_of_row builds, stamped as zennav.bus.Publisher.put stamps it (src, seq, pub_ns), in a
    fraction of the time (the ins's hot path: one per IMU sample at tens of kHz; tests/unit/test_messages.py ties the
    two). The 28 floats go through one struct format whose constant pieces (keys, array headers, float markers) are
    fixed arguments; ints and strings take msgpack's smallest encodings. Not thread-safe (one per publisher)."""

    _ARRAYS = (("llh", 3), ("v_n", 3), ("q_nb", 4), ("euler", 3), ("gyro_bias", 3), ("accel_bias", 3),
               ("std_pos_ned", 3), ("std_v_n", 3), ("std_euler", 3))

    def __init__(self) -> None:
        key = msgpack.packb
        pieces = []  # the constant bytes before each float
        for name, n in self._ARRAYS:
            pieces += [key(name) + bytes((0x90 + n, 0xcb))] + [b"\xcb"] * (n - 1)
        self._floats = struct.Struct(">" + "".join(f"{len(c)}sd" for c in pieces)).pack
        self._args: list = [x for c in pieces for x in (c, 0.0)]
        fields = 3 + len(self._ARRAYS) + 3 + 3  # header, arrays, gnss_state/imu_cseq/imu_pub_ns, src/seq/pub_ns
        self._head = b"\xde" + fields.to_bytes(2, "big") + key("schema") + key("nav_solution") + key("v") + \
            key(SCHEMAS["nav_solution"].version) + key("t_ns")
        self._k_state, self._k_cseq, self._k_imu_pub, self._k_src, self._k_seq, self._k_pub = (
            key(k) for k in ("gnss_state", "imu_cseq", "imu_pub_ns", "src", "seq", "pub_ns"))
        self._strs: dict[object, bytes] = {}

    def _str(self, s) -> bytes:
        """msgpack of str(s), cached by s (a GNSS state, the publisher's src)."""
        b = self._strs.get(s)
        if b is None:
            b = self._strs[s] = msgpack.packb(str(s))
        return b

    def pack(self, t_ns: int, row, std: list, gyro_bias, accel_bias, gnss_state, imu_cseq: int, imu_pub_ns: int,
             src: str, seq: int, pub_ns: int) -> bytes:
        """The message at t_ns [ns] of the navigation state row (10 floats: lat, lon [rad], h [m], v_n [m/s, NED],
        q_nb) with std (9 floats: the 1-sigma of position [m], velocity [m/s], attitude [rad]), the biases (3 floats
        each) and GNSS state, of the IMU sample imu_cseq published at imu_pub_ns, stamped src, seq, pub_ns."""
        args = self._args
        args[1::2] = (*row, *euler_list(row[6], row[7], row[8], row[9]), *gyro_bias, *accel_bias, *std)
        return b"".join((self._head, _int(t_ns), self._floats(*args), self._k_state, self._str(gnss_state),
                         self._k_cseq, _int(imu_cseq), self._k_imu_pub, _int(imu_pub_ns), self._k_src, self._str(src),
                         self._k_seq, _int(seq), self._k_pub, _int(pub_ns)))


def attitude_msg(t_ns: int, q_nb: list, gyro_bias: list, weight: float, omega_in_n, accel_b=None,
                 vel_b=None) -> dict:
    """attitude message of one filter output: q_nb (scalar first), gyro bias [rad/s], rejection weight, the
    omega_in_n [rad/s, NED] applied and, with a velocity source, the accel_b [m/s^2] and vel_b [m/s] applied."""
    return make("attitude", t_ns, q_nb=q_nb, euler=euler_list(*q_nb), gyro_bias=gyro_bias, weight=float(weight),
                omega_in_n=list(omega_in_n), accel_b=None if accel_b is None else list(accel_b),
                vel_b=None if vel_b is None else list(vel_b))


def _finite(x: float, default: float) -> float:
    x = float(x)
    return x if math.isfinite(x) else default


def alignment_map(al: dict) -> dict:
    """Navigator.status()["alignment"] -> the nav_status ``alignment`` map (see check_nav_status)."""
    return {"state": str(al["state"]), "method": str(al.get("method") or ""),
            "heading_std_rad": _finite(al["heading_std_rad"], 1e9),
            "times_ns": {str(k): int(v) for k, v in al.get("times_ns", {}).items()},
            "tilt_source": str(al.get("tilt_source") or ""), "gyrocompass": str(al.get("gyrocompass") or ""),
            "initial_state": str(al.get("initial_state") or ""), "waiting": str(al.get("waiting") or "")}


def noise_map(noise: dict) -> dict:
    """Navigator.status()["measurement_noise"] -> per source {R_diag, ratio, branch[, k, inflate, fading]}: the live
    R diagonal [m^2 or (m/s)^2], its ratio to the reported R (None when R is not adapted) and the seed-001 branch
    taken last ('inflate' / 'fading'; 'fixed' when adaptive R is off)."""
    out = {}
    for src, r in noise.items():
        e: dict = {"R_diag": [float(x) for x in np.diag(np.asarray(r["R"], dtype=float))]}
        if "scale_diag" in r:
            e.update(ratio=[float(x) for x in r["scale_diag"]], branch=str(r.get("branch") or "none"),
                     **{k: int(r[k]) for k in ("k", "inflate", "fading") if k in r})
        else:
            e.update(ratio=None, branch="fixed")
        out[str(src)] = e
    return out


def nav_status_msg(t_ns: int, engine_status: dict | None, stream: dict, rejected: dict, imu_count: int,
                   gnss_count: int, model: dict, aid_counts: dict | None = None) -> dict:
    """nav_status of the ins: the engine's status() (None before a stream: GNSS state 'unknown'), the stream
    progress (zennav.stream.StreamFollower.status plus the ins's own counts), rejections and drops by reason,
    the samples consumed (IMU, GNSS; aid_counts: per aid stream, only when the stream has one) and the learning
    link's model map."""
    st = engine_status or {"counters": {}, "gnss_state": "unknown"}
    extra: dict = {}
    if "alignment" in st:
        extra["alignment"] = alignment_map(st["alignment"])
    if aid_counts:
        extra["aid_counts"] = {str(k): int(v) for k, v in aid_counts.items()}
    if "measurement_noise" in st:
        extra["adaptive_r"] = bool(st.get("adaptive_r", False))
        extra["measurement_noise"] = noise_map(st["measurement_noise"])
    return make("nav_status", t_ns, gnss_state=str(st.get("gnss_state", "unknown")),
                counters={str(k): int(v) for k, v in st.get("counters", {}).items()},
                rejected={str(k): int(v) for k, v in rejected.items()}, imu_count=int(imu_count),
                gnss_count=int(gnss_count), stream=stream, model=model, **extra)
