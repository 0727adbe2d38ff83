"""In-process replay: run the navigation engine over a dataset, withholding GNSS in outage windows; and the one
selection of sensor events (``sensor_events``) and outage syntax (``parse_outage``, ``parse_outage_every``)
that the ingest service shares, so that the bus carries exactly what the replay feeds the engine.

Outage windows are given in seconds from the first IMU sample of the run (the initial-state time).
"""
from __future__ import annotations

import math
import os
import time
from bisect import bisect_right
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from itertools import repeat

import numpy as np

from .messages.sensor import AID_STREAMS
from .nav.aid import OdometerSample
from .nav.navigator import AidReport, Navigator
from .nav.smoother import Recorder, Smoothed, smooth, smooth_rows
from .nav.types import NS, Dataset

JIT_MIN_S = 300.0  # run_replay compiles its loop for this much IMU data or more [s] (use_jit)
LAZY_FIRST = 256  # IMU samples at most that a "lazy" run_replay runs as Python before it loads the compiled loop


@dataclass
class ReplayResult:
    """Per-IMU-epoch solution of a replay: t_ns (N,), llh (N, 3) [rad, rad, m], v_n (N, 3) [m/s], q_nb (N, 4),
    std_pos_ned (N, 3) [m], outage (N,) bool (engine's GNSS state), the withheld windows [(start_ns, end_ns)],
    the aiding reports, the engine's final status and the wall time [s]; with smoothing, the smoothed solution at
    the same rows (a ReplayResult: std_pos_ned smoothed, status the smoother's figures, wall_s forward plus
    smoothing) and the smoother's per-epoch result (zennav.nav.smoother.Smoothed: all states, biases included)."""

    dataset: str
    t_ns: np.ndarray
    llh: np.ndarray
    v_n: np.ndarray
    q_nb: np.ndarray
    std_pos_ned: np.ndarray
    outage: np.ndarray
    windows: list[tuple[int, int]]
    reports: list[AidReport] = field(default_factory=list)
    status: dict = field(default_factory=dict)
    wall_s: float = 0.0
    smoothed: ReplayResult | None = None
    smoothing: Smoothed | None = None


def parse_outage(text: str) -> tuple[float, float]:
    """'START:DURATION' [s] -> (start_s, duration_s); ValueError with the reason when malformed."""
    try:
        start, dur = (float(x) for x in text.split(":"))
    except ValueError:
        raise ValueError(f"expected START:DURATION in seconds, got {text!r}") from None
    if dur <= 0 or start < 0 or not math.isfinite(start + dur):
        raise ValueError(f"START must be >= 0 and DURATION > 0, got {text!r}")
    return start, dur


def parse_outage_every(text: str) -> tuple[float, float, float]:
    """'PERIOD:DURATION[:FIRST]' [s] -> (period_s, duration_s, first_s), FIRST defaulting to PERIOD - DURATION
    (so '90:30' withholds 60..90 s, 150..180 s, ...); ValueError with the reason when malformed."""
    try:
        vals = [float(x) for x in text.split(":")]
    except ValueError:
        raise ValueError(f"expected PERIOD:DURATION[:FIRST] in seconds, got {text!r}") from None
    if len(vals) not in (2, 3) or not all(map(math.isfinite, vals)) or not 0 < vals[1] < vals[0] \
            or (len(vals) == 3 and vals[2] < 0):
        raise ValueError(f"expected PERIOD:DURATION[:FIRST] with 0 < DURATION < PERIOD, FIRST >= 0, got {text!r}")
    period, dur = vals[:2]
    return period, dur, vals[2] if len(vals) == 3 else period - dur


def outage_windows(
    t0_ns: int,
    t_end_ns: int,
    outages: Sequence[tuple[float, float]] = (),
    every: tuple[float, float, float] | None = None,
) -> list[tuple[int, int]]:
    """GNSS-withholding windows [start_ns, end_ns) from (start_s, duration_s) pairs and an optional
    periodic (period_s, duration_s, first_s) pattern, all relative to t0_ns; clipped to the run, sorted."""
    wins = [(t0_ns + int(round(s * NS)), t0_ns + int(round((s + d) * NS))) for s, d in outages]
    if every is not None:
        period, dur, first = every
        if period <= 0 or dur <= 0:
            raise ValueError("--outage-every needs a positive period and duration")
        s = first
        while t0_ns + (s + dur) * NS <= t_end_ns:
            wins.append((t0_ns + int(round(s * NS)), t0_ns + int(round((s + dur) * NS))))
            s += period
    return sorted((a, min(b, t_end_ns)) for a, b in wins if a < t_end_ns)


def run_end_ns(ds: Dataset) -> int:
    """Time of the last IMU sample a run of ds processes [ns]: the last sample, or config.end_t_ns before it."""
    t_last = ds.imu.t_ns[-1]
    return int(t_last if ds.config.end_t_ns is None else min(t_last, ds.config.end_t_ns))


def sensor_events(
    ds: Dataset,
    outages: Sequence[tuple[float, float]] = (),
    outage_every: tuple[float, float, float] | None = None,
) -> tuple[list[tuple[int, int]], list[tuple[str, int]]]:
    """Which IMU samples, GNSS fixes and aid samples (AID_STREAMS) a run feeds the engine, in order: (windows,
    events), events being (kind, k) indices into ds.imu / ds.gnss / ds.dvl / ds.depth. IMU samples after the
    initial-state time up to config.end_t_ns; GNSS fixes after the initial time, outside the outage windows, not
    after the last IMU sample; aid samples likewise, outages or not. A fix or aid sample goes before the first
    IMU sample at or after its time (in time order; ties: GNSS, DVL, depth): the engine fuses a fix at its time
    within that IMU sample, an aid sample right after it (held until then). run_replay and the ingest service
    both take their sequence from here."""
    t_imu = ds.imu.t_ns
    t0 = int(ds.initial.t_ns)
    k0 = int(np.searchsorted(t_imu, t0, side="right"))
    t_last = run_end_ns(ds)
    k1 = int(np.searchsorted(t_imu, t_last, side="right"))
    windows = outage_windows(t0, t_last, list(outages), outage_every)
    t_end = t_imu[k1 - 1] if k1 > k0 else t0
    queued: list[tuple[int, int, int, str, int]] = []  # (IMU position, t_ns, tie rank, kind, index)
    for rank, kind in enumerate(("gnss", *AID_STREAMS)):
        data = getattr(ds, kind)
        if data is None or len(data) == 0:
            continue
        t = data.t_ns
        keep = (t > t0) & (t <= t_end)
        if kind == "gnss":
            for a, b in windows:
                keep &= ~((t >= a) & (t < b))
        idx = np.flatnonzero(keep)
        before = np.searchsorted(t_imu[k0:k1], t[idx], side="left")  # IMU position of each
        queued += zip(before.tolist(), t[idx].tolist(), [rank] * len(idx), [kind] * len(idx), idx.tolist())
    queued.sort()
    events: list[tuple[str, int]] = []
    done = 0  # IMU positions before this one are in events
    for pos, _, _, kind_q, k_q in queued:  # each before the IMU sample at its position
        if pos >= k1 - k0:
            break
        events.extend(zip(repeat("imu"), range(k0 + done, k0 + pos)))
        done = max(done, pos)
        events.append((kind_q, k_q))
    events.extend(zip(repeat("imu"), range(k0 + done, k1)))
    return windows, events


def run_replay(
    ds: Dataset,
    outages: Sequence[tuple[float, float]] = (),
    outage_every: tuple[float, float, float] | None = None,
    navigator: Navigator | None = None,
    compensator=None,
    on_epoch: Callable[[Navigator], None] | None = None,
    smoothing: bool = False,
    epoch_due: Callable[[], int | None] | None = None,
    loop: str | None = None,
) -> ReplayResult:
    """Run the engine over ds from its initial-state time to its end (config.end_t_ns or the last IMU sample).
    GNSS fixes inside the windows are withheld; every other fix is handed over before the first IMU sample
    at or after its time. A compensator (zennav.learn.loop) learns from the engine's training samples and
    answers its queries while GNSS is lost. on_epoch(nav) is called after each IMU epoch (progress, recording;
    it must not change the engine). smoothing: also the forward-backward smoothed solution
    (zennav.nav.smoother) in result.smoothed. The dataset's DVL and depth samples come in the events (the streams
    the bus carries, sensor_events) and its odometer samples from ``aid_streams`` (replay only: the bus has no
    odometer stream yet): each goes to the engine's sources that take it after the first IMU sample at or after its
    time, outages or not, before that epoch's solution (the odometer's first, then the DVL's and depth's in time
    order; zennav.nodes.ins hands the bus's over the same way). A compensator of another target than "drift" runs
    the engine without the drift target's shadow INSs (config.learn_drift: the samples it learns are the same).

    loop: how the IMU samples between two events run: "step" (on_imu, sample by sample), "compiled" (the stretches
    in the engine's compiled block loop, Navigator.run_imu: the same floats), "python" (that block loop as Python, for
    tests and debugging), "lazy" (the first stretch as Python, then numba and the compiled kernels load, about a
    second, and the rest runs compiled: the first samples without waiting for numba, the same floats); None: "lazy"
    where ``use_jit`` says, else "step". The block loop runs only where the
    run needs no step-wise hand-over (no odometer stream, no smoothing; with a compensator, from one learning event
    to the next: Navigator.run_imu); epoch_due() (optional) says
    from which IMU time on_epoch must see the epochs (None: every one); without it on_epoch sees every epoch and the
    run goes step by step; in the block loop on_epoch also sees the last epoch of each stretch."""
    target = getattr(compensator, "target", None)
    config = ds.config if compensator is None else ds.config.with_(
        learning=True, dvl_learned=target == "dvl_beam", learn_drift=target in (None, "drift"))
    nav = navigator or Navigator(config, ds.initial)
    rec = Recorder() if smoothing else None
    nav.recorder = rec
    imu, gnss = ds.imu, ds.gnss
    windows, events = sensor_events(ds, outages, outage_every)
    streams = aid_streams(ds, nav)
    kinds = [kind for kind, _ in events]
    n = kinds.count("imu")
    t_out = np.empty(n, dtype=np.int64)
    out = np.empty((n, 10))
    std = np.empty((n, 3))
    outage = np.zeros(n, dtype=bool)
    reports: list[AidReport] = []
    t_list = imu.t_ns.tolist()
    aid_data = {kind: getattr(ds, kind) for kind in AID_STREAMS}
    held: list[tuple[str, int]] = []  # aid samples waiting for the IMU sample that reaches their time
    if loop is None:
        loop = "lazy" if use_jit(ds) else "step"
    if loop not in ("step", "compiled", "python", "lazy"):
        raise ValueError(f"loop: step, compiled, python or lazy, not {loop!r}")
    blocks = loop != "step" and not streams and rec is None and (on_epoch is None or epoch_due)
    jit = loop == "compiled"
    load_jit = blocks and loop == "lazy"  # numba loads after the first stretch, which runs as Python
    if blocks:
        if jit:
            from .nav.kernels import compiled

            compiled()  # numba loads before the clock starts (start-up, not the loop)
        block_args = (np.ascontiguousarray(imu.t_ns, dtype=np.int64), np.ascontiguousarray(imu.dtheta, dtype=float),
                      np.ascontiguousarray(imu.dvel, dtype=float))
        rows, row_std = np.empty((len(imu), 10)), np.empty((len(imu), 9))
        others = [j for j, kind in enumerate(kinds) if kind != "imu"] + [len(events)]  # events that are not IMU
        dtheta, dvel = block_args[1], block_args[2]  # rows of the samples that go step by step
    else:
        dtheta, dvel = imu.dtheta.tolist(), imu.dvel.tolist()
    i = 0
    e = -1
    wall0 = time.perf_counter()
    waited = 0.0  # [s] loading the compiled kernels ("lazy"): start-up, not the loop
    while e + 1 < len(events):
        e += 1
        kind, k = events[e]
        if kind == "gnss":
            nav.on_gnss(gnss.fix_at(k))
            continue
        if kind != "imu":
            held.append((kind, k))
            continue
        if blocks and not held:
            due = epoch_due() if epoch_due is not None else None
            k_last = events[others[bisect_right(others, e)] - 1][1]  # the last IMU sample before the next event
            if load_jit and i > 0:  # the first samples ran as Python: now the compiled kernels
                w0 = time.perf_counter()
                from .nav.kernels import compiled

                compiled()
                jit, load_jit = True, False
                waited = time.perf_counter() - w0
            k_stop = min(k_last + 1, k + LAZY_FIRST) if load_jit else k_last + 1
            k_end = nav.run_imu(*block_args, k, k_stop, 2**62 if due is None else due, rows, row_std, jit)
            if k_end > k:
                n_run = k_end - k
                t_out[i:i + n_run] = block_args[0][k:k_end]
                out[i:i + n_run] = rows[k:k_end]
                std[i:i + n_run] = row_std[k:k_end, :3]
                outage[i:i + n_run] = nav.gnss_state != "valid"
                i += n_run
                e += n_run - 1
                if on_epoch is not None and (k_end < k_stop or k_stop == k_last + 1):  # not a cut at LAZY_FIRST
                    on_epoch(nav)
                continue
        nav.on_imu(t_list[k], dtheta[k], dvel[k])
        if streams:
            streams.feed(nav, t_list[k])
        for kind_a, k_a in held:
            nav.on_aid(kind_a, aid_data[kind_a].sample(k_a))
        held.clear()
        if compensator is not None:  # answers fused at this sample are in its solution, as the ins publishes it
            compensator.add(nav.pop_samples())
            for query in nav.pop_queries():
                prediction = compensator.predict(query)
                if prediction is not None:
                    nav.on_correction(query, *prediction)
                elif getattr(compensator, "last_refusal", ""):
                    nav.on_refusal(query, compensator.last_refusal)
        s = nav.state
        t_out[i] = nav.t_ns
        out[i] = (s.lat, s.lon, s.h, s.vn, s.ve, s.vd, s.q0, s.q1, s.q2, s.q3)
        std[i] = nav.std_pos_ned
        outage[i] = nav.gnss_state != "valid"
        if rec is not None:
            rec.mark_row(nav.t_ns)
        reports.extend(nav.pop_reports())
        if on_epoch is not None:
            on_epoch(nav)
        i += 1
    wall = time.perf_counter() - wall0 - waited
    nav.recorder = None
    res = ReplayResult(
        dataset=ds.name,
        t_ns=t_out,
        llh=out[:, 0:3].copy(),
        v_n=out[:, 3:6].copy(),
        q_nb=out[:, 6:10].copy(),
        std_pos_ned=std,
        outage=outage,
        windows=windows,
        reports=reports,
        status=nav.status(),
        wall_s=wall,
    )
    if rec is not None:
        res.smoothing, res.smoothed = smoothed_result(res, rec)
    return res


def use_jit(ds: Dataset) -> bool:
    """Whether run_replay compiles its loop: ZENNAV_JIT=1 always, 0 never; by default from JIT_MIN_S of IMU data on
    (loading numba and the cached kernels takes about a second; the compiled loop saves about 0.7 s of CPU per minute
    of 200 Hz data), with a compensator too (its stretches run from one learning event to the next)."""
    flag = os.environ.get("ZENNAV_JIT", "")
    if flag in ("0", "1"):
        return flag == "1"
    t = ds.imu.t_ns
    return len(t) > 1 and (int(t[-1]) - int(t[0])) / NS >= JIT_MIN_S


class AidStreams:
    """The dataset's aid streams that the engine takes, fed in time order up to each IMU time (run_replay):
    (input kind, sample times [ns], sample k -> the sample object) per stream, each with its next index."""

    def __init__(self, streams: list[tuple[str, list[int], Callable[[int], object]]], t0_ns: int):
        self.streams = streams
        self.next = [int(np.searchsorted(t, t0_ns, side="right")) for _, t, _ in streams]

    def __bool__(self) -> bool:
        return bool(self.streams)

    def feed(self, nav: Navigator, t_ns: int) -> None:
        """Hand the engine every sample at or before t_ns not yet handed, earliest first (ties: stream order)."""
        while True:
            best, best_t = -1, t_ns + 1
            for i, (_, times, _) in enumerate(self.streams):
                j = self.next[i]
                if j < len(times) and times[j] < best_t:
                    best, best_t = i, times[j]
            if best < 0:
                return
            kind, _, sample = self.streams[best]
            nav.on_aid(kind, sample(self.next[best]))
            self.next[best] += 1


def aid_streams(ds: Dataset, nav: Navigator) -> AidStreams:
    """The dataset's aid streams that the bus does not carry (the odometer's samples) for the engine's sources that
    take them (their input kinds); the DVL and depth samples come in sensor_events' events."""
    kinds = {kind for src in nav.sources.values() for kind in src.inputs}
    streams: list[tuple[str, list[int], Callable[[int], object]]] = []
    if ds.odometer is not None and "odometer" in kinds:
        odo_t, odo_speed = ds.odometer.t_ns.tolist(), ds.odometer.speed_mps.tolist()
        streams.append(("odometer", odo_t, lambda k: OdometerSample(odo_t[k], odo_speed[k])))
    return AidStreams(streams, nav.t_ns)


def smoothed_result(res: ReplayResult, rec: Recorder) -> tuple[Smoothed, ReplayResult]:
    """The backward pass over a replay's recorded epochs and its rows corrected (forward rows outside the smoothed
    segments keep their forward position 1-sigma)."""
    wall0, cpu0 = time.perf_counter(), time.process_time()
    sm = smooth(rec)
    llh, v_n, q_nb, std, covered = smooth_rows(sm, res.t_ns, res.llh, res.v_n, res.q_nb)
    std_pos = np.where(covered[:, None], std[:, 0:3], res.std_pos_ned)
    wall = time.perf_counter() - wall0
    status = {"smoother": {**sm.stats, "rows_smoothed": int(covered.sum()), "wall_s": wall,
                           "cpu_s": time.process_time() - cpu0}}
    return sm, ReplayResult(res.dataset, res.t_ns, llh, v_n, q_nb, std_pos, res.outage, res.windows, [], status,
                            res.wall_s + wall)
