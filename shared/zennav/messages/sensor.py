"""Sensor messages (ingest -> ins, attitude) and the sensor channel's ordering.

ingest merges all of its sensor streams into one time-ordered sequence (sorted by ``t_ns``; at equal times
GNSS before IMU, so a fix at t is queued before the IMU sample that reaches t) and stamps every sensor
message (stream_start, imu, gnss, stream_end) with ``cseq``, one counter shared by all sensor keys of that
ingest instance (``src``). The sensor keys are published reliably with blocking congestion control and the
same priority, so in practice they arrive in publish order; consumers do not rely on that: they consume
messages strictly in ``cseq`` order (``SequenceMerger``), holding any that arrive early until the missing
ones come. Because the sequence totally orders IMU and GNSS, every fix with ``t_ns`` <= an IMU sample's
``t_ns`` is handed to the core before that sample, without watermarks or timers. A gap that never fills
(only possible if a sample is really lost) is skipped once more than ``max_hold`` messages are held, or at
``stream_end``, and is counted as ``gap``; duplicates (cseq already consumed) are counted and dropped.
An ``imu_batch`` holds N consecutive IMU samples (none of another sensor between them) with cseq c .. c+N-1;
``samples(msg)`` expands it into N ``imu`` messages, which consumers merge like any other.
``stream_start`` describes the sensors and the run (IMU noise model, GNSS lever arm, start/end times, initial
state and its uncertainty, outages withheld), never filter settings: those are the ins's parameter file
(``deploy/ins.yaml``). ``stream_end`` carries the counts so consumers can prove nothing was lost.
"""
from __future__ import annotations

import heapq
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .codec import floats, make
from .schema import ANY, FLOATS, INT, INTS, MAP, OPT, SCHEMAS, SENSOR, STR, VEC, define


def check_imu_batch(msg: dict) -> str:
    """Consistency of an imu_batch (types already checked): '' or 'code: detail'."""
    t, n = msg["t_ns_list"], len(msg["t_ns_list"])
    if n == 0 or len(msg["dt_ns_list"]) != n or len(msg["dtheta"]) != 3 * n or len(msg["dvel"]) != 3 * n:
        return (f"bad_shape: imu_batch of {n} times needs {n} dt_ns and 3x{n} dtheta/dvel, got "
                f"{len(msg['dt_ns_list'])}, {len(msg['dtheta'])}, {len(msg['dvel'])}")
    if t[-1] != msg["t_ns"] or any(b <= a for a, b in zip(t, t[1:])):
        return "bad_value: imu_batch t_ns_list must increase strictly and end at t_ns"
    return ""


define("imu", 1, "IMU increments over (t_prev, t_ns], body frame FRD: dtheta [rad], dvel [m/s]; dt_ns the interval.",
       **SENSOR, dt_ns=INT, dtheta=VEC(3), dvel=VEC(3))
define("imu_batch", 1, "N >= 1 consecutive IMU samples with cseq .. cseq+N-1 (see imu): t_ns_list, dt_ns_list (N "
       "ints, t_ns_list strictly increasing, its last = t_ns), dtheta, dvel (3N floats, sample after sample).",
       check=check_imu_batch, **SENSOR, t_ns_list=INTS, dt_ns_list=INTS, dtheta=FLOATS, dvel=FLOATS)
define("gnss", 1, "GNSS fix: llh [rad, rad, m], std_ned [m]; v_n/std_v_n [m/s] NED or None; fix: FixType; "
       "num_sats (-1 unknown).",
       **SENSOR, llh=VEC(3), std_ned=VEC(3), v_n=OPT(VEC(3)), std_v_n=OPT(VEC(3)), fix=INT, num_sats=INT)
define("stream_start", 1, "Start of a sensor stream: dataset name; config: the sensor description of the run "
       "(zennav.nav.types.NavConfig fields that describe the sensors and the run, SI: imu_noise, lever_arm_b, "
       "start_t_ns, end_t_ns; never filter settings); InitialState (as a map, SI), expected counts per stream, "
       "GNSS outages withheld [[t0_ns, t1_ns], ...].",
       **SENSOR, dataset=STR, config=MAP, initial=MAP, counts=MAP, outages=ANY)
define("stream_end", 1, "End of a sensor stream: counts published per stream and the last cseq.",
       **SENSOR, counts=MAP, last_cseq=INT)


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
    from ..nav.types import GnssFix

    v = msg.get("v_n")
    sv = msg.get("std_v_n")
    return GnssFix(t_ns=int(msg["t_ns"]), llh=np.array(msg["llh"]), std_ned=np.array(msg["std_ned"]),
                   v_n=None if v is None else np.array(v),
                   std_v_n=None if sv is None else np.array(sv),
                   fix=int(msg["fix"]), num_sats=int(msg["num_sats"]))


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
