"""In-process replay: run the navigation engine over a dataset, withholding GNSS in outage windows; and the one
selection of sensor events (``sensor_events``) and outage syntax (``parse_outage``, ``parse_outage_every``)
that the ingest service shares, so that the bus carries exactly what the replay feeds the engine.

Outage windows are given in seconds from the first IMU sample of the run (the initial-state time).
"""
from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from itertools import repeat

import numpy as np

from .datasets.streamed import StreamedImu
from .messages.sensor import AID_STREAMS
from .nav.aid import OdometerSample
from .nav.navigator import AidReport, Navigator
from .nav.rotation import quat_to_euler
from .nav.smoother import Recorder, Smoothed, smooth, smooth_rows
from .nav.types import NS, Dataset, ImuData

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

    @cached_property
    def euler(self) -> np.ndarray:
        """ZYX Euler angles (roll, pitch, yaw) (N, 3) [rad] of q_nb, computed once (the metrics and nav.txt's)."""
        return quat_to_euler(self.q_nb)


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


@dataclass
class EventPlan:
    """What a run feeds the engine, in order (sensor_events): the IMU samples k0 .. k1 - 1 of ds.imu and the other
    events, inserts (k, kind, index): sample ``index`` of ds.<kind> (gnss or an AID_STREAMS kind) before IMU sample
    k; windows: the outage windows [(start_ns, end_ns)]."""

    windows: list[tuple[int, int]]
    k0: int
    k1: int
    inserts: list[tuple[int, str, int]]

    def __iter__(self) -> Iterator[tuple[str, int]]:
        """The plan as (kind, index), IMU samples included, made as they are taken (an hour at 200 Hz as a list
        of tuples is about 70 MB)."""
        done = self.k0  # IMU samples before this one are out
        for k, kind, index in self.inserts:
            yield from zip(repeat("imu"), range(done, k))
            done = k
            yield kind, index
        yield from zip(repeat("imu"), range(done, self.k1))

    def __len__(self) -> int:
        return self.k1 - self.k0 + len(self.inserts)

    def counts(self) -> dict[str, int]:
        """{kind: events of that kind} (imu first)."""
        out = {"imu": self.k1 - self.k0}
        for _, kind, _ in self.inserts:
            out[kind] = out.get(kind, 0) + 1
        return out


def _inserts(ds: Dataset, t_imu: np.ndarray, k0: int, k1: int, t_end: int,
             windows: list[tuple[int, int]]) -> list[tuple[int, str, int]]:
    """EventPlan.inserts: the GNSS fixes outside the windows and the aid samples after the initial-state time, not
    after t_end [ns], each before the first IMU sample k of t_imu[k0:k1] at or after its time (in time order; ties:
    GNSS, DVL, depth); those after the last one left out."""
    t0 = int(ds.initial.t_ns)
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
    return [(k0 + pos, kind, index) for pos, _, _, kind, index in queued if pos < k1 - k0]


def event_plan(
    ds: Dataset,
    outages: Sequence[tuple[float, float]] = (),
    outage_every: tuple[float, float, float] | None = None,
) -> EventPlan:
    """sensor_events' selection as an EventPlan (the IMU samples as a range: no list of them)."""
    t_imu = ds.imu.t_ns
    t0 = int(ds.initial.t_ns)
    k0 = int(np.searchsorted(t_imu, t0, side="right"))
    t_last = run_end_ns(ds)
    k1 = int(np.searchsorted(t_imu, t_last, side="right"))
    windows = outage_windows(t0, t_last, list(outages), outage_every)
    t_end = int(t_imu[k1 - 1]) if k1 > k0 else t0
    return EventPlan(windows, k0, k1, _inserts(ds, t_imu, k0, k1, t_end, windows))


def head_plan(
    ds: Dataset,
    head: ImuData,
    outages: Sequence[tuple[float, float]] = (),
    outage_every: tuple[float, float, float] | None = None,
) -> EventPlan | None:
    """The start of event_plan(ds) that the first IMU samples (head, a prefix of ds.imu) decide without the rest: its
    samples before the head's last, before any outage window can start and not after config.end_t_ns, with the
    events before them (the whole plan's inserts before head_plan.k1, the same); None when there is none."""
    t_imu = head.t_ns
    t0 = int(ds.initial.t_ns)
    t_cut = int(t_imu[-1])  # the whole run goes on after the samples before it (its window clipping too)
    starts = [start for start, _ in outages] + ([outage_every[2]] if outage_every is not None else [])
    t_cut = min([t_cut] + [t0 + int(round(s * NS)) for s in starts])
    if ds.config.end_t_ns is not None:
        t_cut = min(t_cut, int(ds.config.end_t_ns) + 1)
    k0 = int(np.searchsorted(t_imu, t0, side="right"))
    k1 = int(np.searchsorted(t_imu, t_cut, side="left"))
    return EventPlan([], k0, k1, _inserts(ds, t_imu, k0, k1, t_cut - 1, [])) if k1 > k0 else None


def sensor_events(
    ds: Dataset,
    outages: Sequence[tuple[float, float]] = (),
    outage_every: tuple[float, float, float] | None = None,
) -> tuple[list[tuple[int, int]], EventPlan]:
    """Which IMU samples, GNSS fixes and aid samples (AID_STREAMS) a run feeds the engine, in order: (windows,
    events), events (an EventPlan: iterable again and again, not a list) yielding (kind, k) indices into ds.imu /
    ds.gnss / ds.dvl / ds.depth. IMU samples after the
    initial-state time up to config.end_t_ns; GNSS fixes after the initial time, outside the outage windows, not
    after the last IMU sample; aid samples likewise, outages or not. A fix or aid sample goes before the first
    IMU sample at or after its time (in time order; ties: GNSS, DVL, depth): the engine fuses a fix at its time
    within that IMU sample, an aid sample right after it (held until then). run_replay (event_plan, the same
    selection without a list of the IMU samples) and the ingest service both take their sequence from here."""
    plan = event_plan(ds, outages, outage_every)
    return plan.windows, plan


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
    IMU data still being read (zennav.datasets.streamed.StreamedImu) runs from its head first (head_plan), the whole
    read in the background from its first sample on (StreamedImu.prefetch), then the run goes on over the whole: the
    same events, the same floats.

    loop: how the IMU samples between two events run: "step" (on_imu, sample by sample), "compiled" (the stretches
    in the engine's compiled block loop, Navigator.run_imu: the same floats), "python" (that block loop as Python, for
    tests and debugging), "lazy" (the first stretch as Python, then numba and the compiled kernels load, about a
    second, and the rest runs compiled: the first samples without waiting for numba, the same floats); None: "lazy"
    where ``use_jit`` says, else "step" (a head runs "step" then, and "python" with "lazy"). The block loop runs only
    where the run needs no step-wise hand-over (no odometer stream, no smoothing; with a compensator, from one
    learning event to the next: Navigator.run_imu); epoch_due() (optional) says from which IMU time on_epoch must
    see the epochs (None: every one); without it on_epoch sees every epoch and the run goes step by step; in the
    block loop on_epoch also sees the last epoch of each stretch."""
    if loop not in (None, "step", "compiled", "python", "lazy"):
        raise ValueError(f"loop: step, compiled, python or lazy, not {loop!r}")
    target = getattr(compensator, "target", None)
    config = ds.config if compensator is None else ds.config.with_(
        learning=True, dvl_learned=target == "dvl_beam", learn_drift=target in (None, "drift"))
    nav = navigator or Navigator(config, ds.initial)
    rec = Recorder() if smoothing else None
    nav.recorder = rec
    run = _Run(ds, nav, compensator, on_epoch, epoch_due, aid_streams(ds, nav))
    imu = ds.imu
    head = head_plan(ds, imu.head, outages, outage_every) if isinstance(imu, StreamedImu) and imu.pending else None
    if head is not None:  # the samples the head decides, then the rest of the IMU data (loading, not the loop)
        assert isinstance(imu, StreamedImu)
        run.start(head, imu.head, "step" if loop is None else "python" if loop == "lazy" else loop)  # numba: after
        run.advance(head, head.k0 + 1)  # the first sample; then the rest of the file is read beside the head's run
        imu.prefetch()
        run.advance(head, None)
        w0 = time.perf_counter()
        if loop in (None, "lazy") and use_jit(ds, imu.span_s):  # numba loads beside the read (as the whole would)
            from .nav.kernels import compiled

            compiled()
        imu.whole()
        run.waited += time.perf_counter() - w0
    plan = event_plan(ds, outages, outage_every)  # the whole IMU data from here on
    if head is not None and (plan.k0, plan.inserts[:len(head.inserts)]) != (head.k0, head.inserts):
        raise RuntimeError("head_plan is not the start of event_plan")  # a bug, not the data's
    run.start(plan, ds.imu, loop or ("lazy" if use_jit(ds) else "step"))
    run.advance(plan, plan.k1)
    wall = time.perf_counter() - run.wall0 - run.waited
    nav.recorder = None
    res = ReplayResult(
        dataset=ds.name,
        t_ns=run.t_out,
        llh=run.out[:, 0:3].copy(),
        v_n=run.out[:, 3:6].copy(),
        q_nb=run.out[:, 6:10].copy(),
        std_pos_ned=run.std,
        outage=run.outage,
        windows=plan.windows,
        reports=run.reports,
        status=nav.status(),
        wall_s=wall,
    )
    if rec is not None:
        res.smoothing, res.smoothed = smoothed_result(res, rec)
    return res


class _Run:
    """run_replay's loop: the engine fed an EventPlan's events (advance), its solution rows collected; start() sets
    the IMU data and the plan (a head's, then the whole's: the rows so far kept)."""

    def __init__(self, ds: Dataset, nav: Navigator, compensator, on_epoch: Callable[[Navigator], None] | None,
                 epoch_due: Callable[[], int | None] | None, streams: AidStreams):
        self.ds, self.nav, self.compensator, self.on_epoch, self.epoch_due = ds, nav, compensator, on_epoch, epoch_due
        self.streams = streams
        self.block_ok = not streams and nav.recorder is None and (on_epoch is None or epoch_due is not None)
        self.aid_data = {kind: getattr(ds, kind) for kind in AID_STREAMS}
        self.held: list[tuple[str, int]] = []  # aid samples waiting for the IMU sample that reaches their time
        self.reports: list[AidReport] = []
        self.i = 0  # solution rows so far
        self.k = -1  # the next IMU sample (-1: before start)
        self.j = 0  # the next insert of the plan
        self.t_out = np.empty(0, dtype=np.int64)
        self.out, self.std, self.outage = np.empty((0, 10)), np.empty((0, 3)), np.zeros(0, dtype=bool)
        self.wall0 = 0.0
        self.waited = 0.0  # [s] loading the compiled kernels ("lazy") or the rest of the IMU data: not the loop

    def start(self, plan: EventPlan, imu: ImuData, loop: str) -> None:
        """Run plan over imu from here (the first plan's k0, else where the last one stopped) with ``loop``
        (run_replay's)."""
        self.blocks = loop != "step" and self.block_ok
        self.jit = loop == "compiled"
        self.load_jit = self.blocks and loop == "lazy"  # numba loads after the first stretch, which runs as Python
        if self.blocks:
            if self.jit:
                from .nav.kernels import compiled

                compiled()  # numba loads before the clock starts (start-up, not the loop)
            self.block_args = (np.ascontiguousarray(imu.t_ns, dtype=np.int64),
                               np.ascontiguousarray(imu.dtheta, dtype=float),
                               np.ascontiguousarray(imu.dvel, dtype=float))
            self.rows, self.row_std = np.empty((len(imu), 10)), np.empty((len(imu), 9))
            self.dtheta, self.dvel = self.block_args[1], self.block_args[2]  # rows of the samples that go step by step
        else:
            self.dtheta, self.dvel = imu.dtheta.tolist(), imu.dvel.tolist()
        self.t_list = imu.t_ns.tolist()
        n, i = plan.k1 - plan.k0, self.i
        self.t_out = np.concatenate([self.t_out[:i], np.empty(n - i, dtype=np.int64)])
        self.out = np.concatenate([self.out[:i], np.empty((n - i, 10))])
        self.std = np.concatenate([self.std[:i], np.empty((n - i, 3))])
        self.outage = np.concatenate([self.outage[:i], np.zeros(n - i, dtype=bool)])
        if self.k < 0:
            self.k = plan.k0
            self.wall0 = time.perf_counter()

    def advance(self, plan: EventPlan, k_end: int | None) -> None:
        """Feed the engine the plan's events up to IMU sample k_end (None: plan.k1, a head's end, not a stretch's);
        the events before IMU sample k_end stay for the next call."""
        nav, ins, held, on_epoch, compensator = self.nav, plan.inserts, self.held, self.on_epoch, self.compensator
        gnss, aid_data, streams, t_list = self.ds.gnss, self.aid_data, self.streams, self.t_list
        t_out, out, std, outage, dtheta, dvel = self.t_out, self.out, self.std, self.outage, self.dtheta, self.dvel
        k_stop_all = plan.k1 if k_end is None else k_end
        i, j, k = self.i, self.j, self.k
        while k < k_stop_all:
            while j < len(ins) and ins[j][0] == k:  # the events before IMU sample k
                _, kind, index = ins[j]
                j += 1
                if kind == "gnss":
                    nav.on_gnss(gnss.fix_at(index))
                else:
                    held.append((kind, index))
            due = None if not self.blocks or held else 2**62 if self.epoch_due is None else self.epoch_due()
            if due is not None:  # (epoch_due() None: on_epoch sees every epoch, step by step)
                k_next = ins[j][0] if j < len(ins) else k_end  # the next event's IMU sample (None: not known)
                if self.load_jit and i > 0:  # the first samples ran as Python: now the compiled kernels
                    w0 = time.perf_counter()
                    from .nav.kernels import compiled

                    compiled()
                    self.jit, self.load_jit = True, False
                    self.waited += time.perf_counter() - w0
                k_stop = min(k_stop_all if k_next is None else k_next, k + LAZY_FIRST if self.load_jit else k_stop_all)
                k_run = nav.run_imu(*self.block_args, k, k_stop, due, self.rows, self.row_std, self.jit)
                if k_run > k:
                    n_run = k_run - k
                    t_out[i:i + n_run] = self.block_args[0][k:k_run]
                    out[i:i + n_run] = self.rows[k:k_run]
                    std[i:i + n_run] = self.row_std[k:k_run, :3]
                    outage[i:i + n_run] = nav.gnss_state != "valid"
                    i += n_run
                    k = k_run
                    if on_epoch is not None and (k_run < k_stop or k_stop == k_next):  # not a cut (LAZY_FIRST, head)
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
            if nav.recorder is not None:
                nav.recorder.mark_row(nav.t_ns)
            self.reports.extend(nav.pop_reports())
            if on_epoch is not None:
                on_epoch(nav)
            i += 1
            k += 1
        self.i, self.j, self.k = i, j, k


def use_jit(ds: Dataset, span_s: float | None = None) -> bool:
    """Whether run_replay compiles its loop: ZENNAV_JIT=1 always, 0 never; by default from JIT_MIN_S of IMU data on
    (loading numba and the cached kernels takes about a second; the compiled loop saves about 0.7 s of CPU per minute
    of 200 Hz data), with a compensator too (its stretches run from one learning event to the next). span_s: the IMU
    data's span [s] if known otherwise (an estimate before it is read: the loop gives the same floats either way)."""
    flag = os.environ.get("ZENNAV_JIT", "")
    if flag in ("0", "1"):
        return flag == "1"
    if span_s is None:
        t = ds.imu.t_ns
        span_s = (int(t[-1]) - int(t[0])) / NS if len(t) > 1 else 0.0
    return span_s >= JIT_MIN_S


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
