"""Sensor messages (ingest -> ins, attitude) and the sensor channel's ordering.

ingest merges all of its sensor streams into one time-ordered sequence (sorted by ``t_ns``; at equal times
GNSS before IMU, so a fix at t is queued before the IMU sample that reaches t) and stamps every sensor
message (stream_start, imu, gnss, dvl, depth, stream_end) with ``cseq``, one counter shared by all sensor keys of that
ingest instance (``src``). The sensor keys are published reliably with blocking congestion control and the
same priority, so in practice they arrive in publish order; consumers do not rely on that: they consume
messages strictly in ``cseq`` order (``SequenceMerger``), holding any that arrive early until the missing
ones come. Because the sequence totally orders IMU and GNSS, every fix with ``t_ns`` <= an IMU sample's
``t_ns`` is handed to the core before that sample, without watermarks. No single message can stall the merge:
its reorder window is bounded (in cseqs held and in idle time), a message far ahead of it is dropped, a
message refused by the consumer's rule (``accept``: zennav.stream checks the stream's time chain) leaves its
slot open for the genuine one, and a gap that never fills (a message really lost) is skipped and counted as
``gap``; duplicates (cseq already consumed) are counted and dropped.
An ``imu_batch`` holds N consecutive IMU samples (none of another sensor between them) with cseq c .. c+N-1;
``samples(msg)`` expands it into N ``imu`` messages, which consumers merge like any other.
A ``dvl`` or ``depth`` sample goes right after the first IMU sample at or after its time (the in-process replay
hands it to the engine there, zennav.replay.sensor_events); at one IMU sample, in time order, DVL first at ties.
``stream_start`` describes the sensors and the run (IMU noise model, GNSS lever arm, start/end times, initial
state and its uncertainty, outages withheld), never filter settings: those are the ins's parameter file
(``deploy/ins.yaml``). ``stream_end`` carries the counts so consumers can prove nothing was lost.
"""
from __future__ import annotations

import heapq
import math
import time
from collections import Counter
from collections.abc import Callable
from typing import Any

import numpy as np

from .codec import floats, make
from .schema import ANY, BOOL, FLOAT, FLOATS, INT, INTS, MAP, OPT, SCHEMAS, SENSOR, STR, VEC, define


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
def check_dvl(msg: dict) -> str:
    """Consistency of a dvl message (types, lengths and finiteness already checked): '' or 'code: detail'. Beams
    come with their four validity flags, velocity_d with its one; at least one of the two."""
    beams, valid, v_d, v_valid = (msg.get(f) for f in ("beams", "beam_valid", "velocity_d", "velocity_valid"))
    if beams is None and v_d is None:
        return "missing_field: dvl needs beams or velocity_d"
    if (beams is None) != (valid is None):
        return "bad_shape: dvl beams and beam_valid come together"
    if valid is not None and (type(valid) is not list or len(valid) != 4 or any(type(b) is not bool for b in valid)):
        return "bad_type: dvl beam_valid must be a list of 4 bools"
    if (v_d is None) != (v_valid is None):
        return "bad_shape: dvl velocity_d and velocity_valid come together"
    return ""


define("dvl", 1, "Doppler velocity log sample of the DVL at its lever arm point (over the bottom): beams [m/s] the 4 "
       "beam velocities (zennav.nav.beams, DVL frame d) with beam_valid (4 bools: bottom lock), and/or velocity_d "
       "[m/s] the velocity in the DVL frame with velocity_valid (bool); an invalid value travels as 0.0 and is "
       "never used. The beam geometry is the stream's sensor description (stream_start config dvl_*).",
       check=check_dvl, **SENSOR, beams=OPT(VEC(4)), beam_valid=OPT(ANY), velocity_d=OPT(VEC(3)),
       velocity_valid=OPT(BOOL))
define("depth", 1, "Pressure depth sensor sample: depth_m [m, positive down] (zennav.nav.types.DepthData).",
       **SENSOR, depth_m=FLOAT)
define("stream_start", 1, "Start of a sensor stream: dataset name; config: the sensor description of the run "
       "(zennav.nav.types.NavConfig fields that describe the sensors and the run, SI: imu_noise, lever_arm_b, "
       "start_t_ns, end_t_ns, dvl_*; never filter settings); InitialState (as a map, SI), expected counts per stream "
       "(imu, gnss; dvl, depth where the run has them), "
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


AID_STREAMS = ("dvl", "depth")  # a dataset's aid streams that travel on the sensor keys (Dataset attributes)


def _wire(values, valid) -> list:
    """Float list for the wire: the values, 0.0 where not valid (NaN cannot travel: the validator refuses it)."""
    return [float(x) if ok else 0.0 for x, ok in zip(values, valid)]


def dvl_msg(sample, cseq: int) -> dict:
    """zennav.nav.types.DvlSample -> dvl message (a valid value that is not finite travels as invalid)."""
    msg = make("dvl", sample.t_ns, cseq=int(cseq))
    if sample.beams is not None:
        valid = [bool(ok) and math.isfinite(x) for x, ok in zip(sample.beams.tolist(), sample.beam_valid.tolist())]
        msg.update(beams=_wire(sample.beams, valid), beam_valid=valid)
    if sample.velocity_d is not None:
        ok = bool(sample.velocity_valid) and bool(np.isfinite(sample.velocity_d).all())
        msg.update(velocity_d=_wire(sample.velocity_d, [ok] * 3), velocity_valid=ok)
    return msg


def dvl_sample(msg: dict):
    """dvl message -> zennav.nav.types.DvlSample (NaN where a value is not valid)."""
    from ..nav.types import DvlSample

    beams = valid = v_d = None
    if msg.get("beams") is not None:
        valid = np.array(msg["beam_valid"], dtype=bool)
        beams = np.where(valid, msg["beams"], np.nan)
    if msg.get("velocity_d") is not None:
        v_d = np.array(msg["velocity_d"]) if msg["velocity_valid"] else np.full(3, np.nan)
    return DvlSample(int(msg["t_ns"]), beams, valid, v_d, msg.get("velocity_valid"))


def depth_msg(sample, cseq: int) -> dict:
    """zennav.nav.types.DepthSample -> depth message."""
    return make("depth", sample.t_ns, cseq=int(cseq), depth_m=float(sample.depth_m))


def depth_sample(msg: dict):
    """depth message -> zennav.nav.types.DepthSample."""
    from ..nav.types import DepthSample

    return DepthSample(int(msg["t_ns"]), float(msg["depth_m"]))


def aid_msg(kind: str, sample, cseq: int) -> dict:
    """The message of one sample of an aid stream (AID_STREAMS): a DvlSample or a DepthSample."""
    return dvl_msg(sample, cseq) if kind == "dvl" else depth_msg(sample, cseq)


def aid_sample(msg: dict):
    """A validated dvl or depth message -> its zennav.nav.types sample (DvlSample, DepthSample)."""
    return dvl_sample(msg) if msg["schema"] == "dvl" else depth_sample(msg)


class SequenceMerger:
    """Releases items strictly in ``cseq`` order so that no single message can stall it (see the module
    docstring). Rules, each counted under its name in ``counts``:

    - ``duplicate``: cseq already released, or ``max_candidates`` items already held for it;
    - ``far_ahead``: cseq at or beyond ``next + window``: dropped, unless ``resync_run`` of them arrive with
      consecutive cseqs (the stream really jumped ahead: the slots before the run are skipped as a gap);
    - ``reordered``: held until its turn (up to ``max_candidates`` candidates per cseq);
    - at its turn a cseq's candidates are offered, in arrival order, to ``accept(cseq, item) -> ''`` or a reason
      (counted under the reason); the first accepted is emitted; when none is, the slot stays open (the genuine
      item may still come);
    - ``gap``: a missing cseq is skipped once it has been waited for ``timeout_s`` (wall clock, not counting the
      time the consumer spends in ``emit``; checked at each push and by ``expire``), once more than ``max_hold``
      cseqs are held, or at ``flush`` (stream end).
    So a bad item costs at most its own slot, and a lost one a counted gap."""

    def __init__(self, next_cseq: int = 0, max_hold: int = 1 << 16, accept: Callable[[int, Any], str] | None = None,
                 window: int = 1 << 16, max_candidates: int = 4, resync_run: int = 8, timeout_s: float = 5.0):
        self.next = next_cseq
        self.max_hold, self.window, self.max_candidates = max_hold, window, max_candidates
        self.resync_run, self.timeout_s = resync_run, timeout_s
        self.accept = accept or (lambda cseq, item: "")
        self._slots: dict[int, list] = {}  # cseq -> candidates, in arrival order
        self._heap: list[int] = []  # the held cseqs
        self._run: list[tuple[int, Any]] = []  # consecutive far-ahead items (a jump of the stream?)
        self._emit_s = 0.0  # [s] spent in emit (the consumer's time, not waiting)
        self._hole_since = 0.0  # _clock() when cseq next began to be waited for (items held)
        self.counts: Counter[str] = Counter()

    def _clock(self) -> float:
        return time.monotonic() - self._emit_s

    def _emit(self, emit: Callable[[Any], None], item) -> None:
        t0 = time.monotonic()
        emit(item)
        self._emit_s += time.monotonic() - t0

    def push(self, cseq: int, item, emit: Callable[[Any], None]) -> None:
        if cseq < self.next:
            self.counts["duplicate"] += 1
            return
        if cseq >= self.next + self.window:
            self._far(cseq, item, emit)
            return
        if cseq == self.next and not self._heap:  # the common case: in order, nothing held
            reason = self.accept(cseq, item)
            if not reason:
                self.next += 1
                emit(item)
                return
            self.counts[reason] += 1  # refused: the slot stays open for the genuine item
            return
        slot = self._slots.get(cseq)
        if slot is None:
            if not self._heap:
                self._hole_since = self._clock()
            slot = self._slots[cseq] = []
            heapq.heappush(self._heap, cseq)
        elif len(slot) >= self.max_candidates:
            self.counts["duplicate"] += 1
            return
        self.counts["reordered"] += 1
        slot.append(item)
        self._drain(emit)
        while self._heap and (len(self._heap) > self.max_hold or self._overdue()):
            self._skip_gap(emit)

    def _overdue(self) -> bool:
        return self._clock() - self._hole_since > self.timeout_s

    def _far(self, cseq: int, item, emit) -> None:
        self.counts["far_ahead"] += 1
        if self._run and cseq != self._run[-1][0] + 1:
            self._run = []
        self._run.append((cseq, item))
        if len(self._run) < self.resync_run:
            return
        run, self._run = self._run, []
        self.counts["far_ahead"] -= len(run)
        self.counts["resync"] += 1
        self.flush(emit)  # release what is held before the jump, then skip to it
        self.counts["gap"] += run[0][0] - self.next
        self.next = run[0][0]
        for c, it in run:
            self.push(c, it, emit)

    def _drain(self, emit) -> None:
        h = self._heap
        moved = False
        while h and h[0] == self.next:
            slot = self._slots[self.next]
            while slot:
                it = slot.pop(0)
                reason = self.accept(self.next, it)
                if not reason:
                    break
                self.counts[reason] += 1
            else:
                break  # every candidate refused: the slot stays open
            heapq.heappop(h)
            del self._slots[self.next]
            self.next += 1
            moved = True
            self._emit(emit, it)
        if moved and h:  # a new hole: waited for from now
            self._hole_since = self._clock()

    def _skip_gap(self, emit) -> None:
        """Skip the missing cseqs before the first held one (or an open slot whose candidates were refused)."""
        h = self._heap
        if h[0] == self.next and not self._slots[self.next]:  # open slot, its candidates refused
            heapq.heappop(h)
            del self._slots[self.next]
            self.counts["gap"] += 1
            self.next += 1
        if h and h[0] > self.next:
            self.counts["gap"] += h[0] - self.next
            self.next = h[0]
        self._hole_since = self._clock()
        self._drain(emit)

    def hole(self) -> tuple[int, int, float] | None:
        """The missing cseqs that held items wait behind (first, last) and how long [s] it has been waited for;
        None when nothing waits behind a missing cseq."""
        if not self._heap or self._heap[0] == self.next:  # nothing held, or an open slot (its candidates refused)
            return None
        return self.next, self._heap[0] - 1, self._clock() - self._hole_since

    def advance(self, n: int) -> bool:
        """n items in order at cseq next, each accepted as push would (the caller checked them): next moves past
        them, as n pushes of the common case. False (nothing done) unless nothing is held."""
        if self._heap:
            return False
        self.next += n
        return True

    def touch(self) -> None:
        """The hole is being filled (a backfill): wait timeout_s more for it before it is skipped."""
        self._hole_since = self._clock()

    def skip_to(self, cseq: int, emit: Callable[[Any], None]) -> None:
        """The cseqs before cseq (at most up to the first held one) are known lost: skip them as a counted gap
        and release what follows."""
        cseq = min(cseq, self._heap[0]) if self._heap else cseq
        if cseq > self.next:
            self.counts["gap"] += cseq - self.next
            self.next = cseq
            self._hole_since = self._clock()
            self._drain(emit)

    def expire(self, emit: Callable[[Any], None]) -> None:
        """Skip the gaps waited for longer than timeout_s (call periodically: the stream may have stopped
        behind a lost message)."""
        while self._heap and self._overdue():
            self._skip_gap(emit)

    def flush(self, emit) -> None:
        while self._heap:
            self._skip_gap(emit)

    @property
    def held(self) -> int:
        return sum(len(s) for s in self._slots.values())
