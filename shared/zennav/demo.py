"""`zennav demo`: the whole process set on loopback, the learning loop over the bus, scored against the truth.

1. Launches deploy/demo.yaml on a free loopback port (zennav.launch): router, two ins, attitude, trainer,
   predictor, monitor, record and ingest, each a process. ingest streams the dataset (default: the built-in
   simulated car drive) with GNSS withheld in the outage windows, as fast as the pipeline drains without loss.
   The ins ``ins`` runs the learning loop: its training samples go to the trainer, which publishes versioned
   parameter sets; in the outages its queries go to the predictor, which answers with the set trained through
   the query's sample count, and the ins fuses the answers. Both run in lockstep (``--lockstep``: the ins waits
   for each answer before its next sample, the predictor for the set the query names), so the distributed run
   is reproducible. The second ins, ``ins-plain`` (learning off, outputs under nav/plain/...), navigates the
   same stream: the no-learning row is measured over the bus too. ``zennav record`` writes every key to MCAP.
2. Meanwhile a thread runs the same data in process (zennav.replay): the plain replay and the replay with the
   in-process learning loop (zennav.learn.loop: the trainer's Learner and the predictor's PredictorCore with
   the same settings and seed). Both use the ins's filter parameter file (deploy/ins.yaml).
3. Checks that no sample was lost or duplicated, compares each distributed solution with its in-process twin
   (prints the largest differences), scores both against the truth, prints what the learning loop did over
   the bus (sets published and used, queries answered, refused and late, answers fused and rejected) and says
   plainly when learning could not help; writes nav.txt, nav.csv, metrics.json (the learned solution),
   no-learning/ (the same for the plain ins), PNG plots (with the plain replay smoothed forward-backward beside
   the two solutions over the bus, zennav.nav.smoother) and the services' log.

Any service that fails, a set that does not come up, or a run that outlasts its time limit stops every
process and raises click.ClickException (exit code 1) with the tail of the services' log.
"""
from __future__ import annotations

import os
import shutil
import socket
import tempfile
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, TextIO, TypeVar

import click
import numpy as np

from .launch import Launcher, load_launch
from .learn.signing import generate as generate_keys
from .metrics import antenna_llh, evaluate, format_table, ned_errors, write_outputs
from .nav.types import NS
from .replay import ReplayResult, run_end_ns, run_replay

if TYPE_CHECKING:  # zenoh is imported when the demo opens its bus
    from .bus import Bus

DEMO_LAUNCH = Path(__file__).resolve().parents[2] / "deploy" / "demo.yaml"
TARGET = "body_velocity"  # the target variant the demo's learning loop learns (zennav.nav.learning)
PLAIN_PREFIX = "plain"  # nav prefix of the second ins, the one without learning (zennav-ins --nav-prefix)
RUNS = {"": "learned", PLAIN_PREFIX: "no learning"}  # nav prefix -> run


@dataclass
class DemoSpec:
    """What the demo streams: a dataset spec (zennav.datasets.registry) with loader options, GNSS outage windows
    (start_s, duration_s) and/or a periodic pattern (period_s, duration_s, first_s), the learned compensation
    (zennav.learn.settings.COMPENSATIONS) and its model seed."""

    dataset: str = "sim:car"
    options: dict = field(default_factory=dict)
    outages: list = field(default_factory=list)
    every: tuple | None = None
    compensation: str = "anfis"
    seed: int = 0


@dataclass
class Pipeline:
    """What one ins of the distributed run produced: the solution as a ReplayResult, its final nav_status
    message and the number of its solutions in the recording."""

    result: ReplayResult
    status: dict
    recorded: int


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _with_options(cmd: list, options: dict[str, list[str]]) -> list:
    """cmd with every ``flag VALUE`` pair of the given flags removed, then each flag added with its values
    (one pair per value)."""
    out, i = [], 0
    while i < len(cmd):
        if cmd[i] in options:
            i += 2
            continue
        out.append(cmd[i])
        i += 1
    for flag, values in options.items():
        for v in values:
            out += [flag, str(v)]
    return out


def _set_arg(cmd: list, flag: str, value: str, service: str) -> None:
    """Replace the value that follows ``flag`` in a launch-file command."""
    try:
        cmd[cmd.index(flag) + 1] = value
    except (ValueError, IndexError):
        raise click.ClickException(f"the launch file's {service} command has no '{flag} VALUE' to set") from None


class _Tee:
    """The launcher's output: every line to the log file; the launcher's own lines and the services'
    warnings and errors also to the terminal."""

    def __init__(self, f: TextIO) -> None:
        self.f = f
        self.tail: deque[str] = deque(maxlen=40)

    def write(self, text: str) -> None:
        self.f.write(text)
        self.tail.append(text.rstrip("\n"))
        if text.startswith("[launch") or " WARNING " in text or " ERROR " in text:
            click.echo(text.rstrip("\n"))

    def flush(self) -> None:
        self.f.flush()


class _Collector:
    """The distributed run as the demo process receives it (lossless fifo subscriptions): the stream start,
    every solution and the end-of-stream status of each ins (by nav prefix); ``complete`` is set once all are
    in."""

    def __init__(self, bus: Bus, prefixes: tuple[str, ...] = tuple(RUNS)) -> None:
        from .messages import Keys

        self.start: dict | None = None
        self.status: dict[str, dict] = {}
        self.solutions: dict[str, list[dict]] = {p: [] for p in prefixes}
        self.solution_keys: dict[str, str] = {}
        self.complete = threading.Event()
        self._lock = threading.Lock()
        bus.subscribe(bus.keys.stream(), self._on_stream, channel="fifo", name="demo-stream")
        for prefix in prefixes:
            k = Keys(bus.keys.vehicle, nav_prefix=prefix)
            self.solution_keys[prefix] = k.nav_solution()
            bus.subscribe(k.nav_solution(), partial(self._on_solution, prefix), channel="fifo", capacity=65536,
                          name=f"demo-solution{prefix}")
            bus.subscribe(k.nav_status(), partial(self._on_status, prefix), channel="fifo",
                          name=f"demo-status{prefix}")

    def _on_stream(self, key: str, msg: dict, recv_ns: int) -> None:
        if msg["schema"] == "stream_start":
            self.start = msg

    def _on_solution(self, prefix: str, key: str, msg: dict, recv_ns: int) -> None:
        self.solutions[prefix].append(msg)
        self._check()

    def _on_status(self, prefix: str, key: str, msg: dict, recv_ns: int) -> None:
        if msg["stream"].get("done"):
            self.status[prefix] = msg
            self._check()

    def _check(self) -> None:
        with self._lock:
            if all(p in self.status and len(self.solutions[p]) >= self.status[p]["stream"]["solutions"]
                   for p in self.solutions):
                self.complete.set()


class _DemoLauncher(Launcher):
    """A Launcher that stops the set once the recorder has finished and the demo has every solution, or as
    soon as a service fails or the run outlasts ``limit_s``."""

    def __init__(self, spec, out, bus, complete: threading.Event, limit_s: float):
        super().__init__(spec, out, bus_factory=lambda: bus)
        self.complete = complete
        self.limit_s = limit_s
        self.deadline = time.monotonic() + limit_s
        self.failed: list[str] = []
        self.completed = False

    def _check_children(self, until: str | None = None) -> bool:
        super()._check_children()
        self.failed = [f"{c.spec.name} exited with code {p.returncode}" for c in self.children.values()
                       if c.finished and (p := c.proc) is not None and p.returncode != 0]
        if not self.failed and time.monotonic() > self.deadline:
            self.failed = [f"the stream did not finish within {self.limit_s:.0f} s"]
        self.completed = not self.failed and self.children["record"].finished and self.complete.is_set()
        return self.completed or bool(self.failed)


_T = TypeVar("_T")


def _background(fn: Callable[[], _T]) -> Callable[[], _T]:
    """Run fn in a daemon thread; the returned callable joins it and returns its result (or raises)."""
    box: dict = {}

    def run() -> None:
        try:
            box["value"] = fn()
        except Exception as e:  # re-raised in the caller's thread
            box["error"] = e

    t = threading.Thread(target=run, name="zennav-demo-inprocess", daemon=True)
    t.start()

    def result():
        t.join()
        if "error" in box:
            raise box["error"]
        return box["value"]

    return result


def run_set(launch_file: Path, out: Path, spec: DemoSpec, settings, limit_s: float,
            during: Callable[[Launcher, _Collector], object] | None = None,
            prefixes: tuple[str, ...] = tuple(RUNS), target: str = TARGET) -> tuple[Path, _Collector]:
    """Launch the process set until the recorder and the demo have every solution of each ins (prefixes: their
    nav prefixes); returns the recording's path and what the demo received. settings: the learning loop's (the
    trainer gets them, with the target variant it learns). during(launcher, collector): run in a thread while the
    set runs (benchmarks/fault_injection.py kills services with it)."""
    from .bus import Bus

    if not launch_file.is_file():
        raise click.ClickException(f"{launch_file} not found (it ships in the source tree's deploy/; "
                                   "or give --launch-file)")
    recording = out / "demo.mcap"
    recording.unlink(missing_ok=True)
    launch = load_launch(launch_file, {"rendezvous": f"tcp/127.0.0.1:{free_port()}"})
    svc = {s.name: s for s in launch.services}
    for need in ("record", "ingest", "trainer"):
        if need not in svc:
            raise click.ClickException(f"{launch_file} has no '{need}' service")
    _set_arg(svc["record"].command, "--", str(recording), "record")
    ingest = svc["ingest"].command
    if len(ingest) < 2 or ingest[1].startswith("-"):
        raise click.ClickException(f"{launch_file}: the ingest command must name its dataset first")
    ingest[1] = spec.dataset
    svc["ingest"].command = _with_options(ingest, {
        "-o": [f"{k}={v if isinstance(v, str) else repr(v)}" for k, v in spec.options.items()],  # zennav-ingest -o
        "--outage": [f"{s!r}:{d!r}" for s, d in spec.outages],
        "--outage-every": [":".join(repr(float(x)) for x in spec.every)] if spec.every else []})
    svc["trainer"].command = _with_options(svc["trainer"].command, {
        "--model": [settings.model], "--optimizer": [settings.optimizer], "--seed": [settings.seed],
        "--targets": [target]})
    # a throwaway parameter-set signing pair and a fresh version state: the run's sets are signed, v1, v2, ...
    keys = Path(tempfile.mkdtemp(prefix="zennav-demo-keys-"))
    private, public = generate_keys(keys)
    svc["trainer"].env.update(ZENNAV_SIGNING_KEY=str(private), ZENNAV_STATE_DIR=str(keys / "state"))
    if "predictor" in svc:
        svc["predictor"].env.update(ZENNAV_VERIFY_KEY=str(public))
    for k in ("ZENNAV_LISTEN", "ZENNAV_ZENOH_CONFIG"):  # the set's own loopback endpoints and configs only
        os.environ.pop(k, None)
    log = out / "launch.log"
    click.echo(f"process set {launch_file} ({len(launch.services)} processes), rendezvous {launch.rendezvous}, "
               f"multicast scouting off; full log: {log}")
    bus = Bus(f"demo-{os.getpid()}", launch.vehicle, mode="peer", connect=[launch.rendezvous],
              listen=["tcp/127.0.0.1:0"], token=False)
    collector = _Collector(bus, prefixes)
    with open(log, "w") as f:
        tee = _Tee(f)
        launcher = _DemoLauncher(launch, tee, bus, collector.complete, limit_s=launch.up_timeout_s + limit_s)
        if during is not None:
            threading.Thread(target=during, args=(launcher, collector), name="zennav-demo-during",
                             daemon=True).start()
        try:
            rc = launcher.run()
        finally:
            bus.close()
            shutil.rmtree(keys, ignore_errors=True)
    if launcher.completed:
        return recording, collector
    if rc == 0 and not launcher.failed:
        raise click.Abort()  # Ctrl-C: every process was stopped
    click.echo("\n".join(["", f"last lines of {log}:", *tee.tail]), err=True)
    said = [line.split("] ", 1)[1] for line in tee.tail if line.startswith("[launch") and
            ("timeout" in line or "error:" in line)]
    why = "; ".join(launcher.failed or said[-1:]) or "the process set did not come up"
    raise click.ClickException(f"demo failed: {why} (every process was stopped; full log: {log})")


def pipeline_result(got: _Collector, prefix: str, recorded: dict[str, int], label: str = "") -> Pipeline:
    """One ins's distributed solution as a ReplayResult, checked: nothing lost or duplicated between ingest,
    that ins, the demo and the recording (recorded: messages per key; the DVL and depth samples too where the
    stream has them); raises ClickException otherwise. label: the ins's name in messages (default: RUNS)."""
    start, status, sols = got.start, got.status[prefix], got.solutions[prefix]
    if start is None:
        raise click.ClickException("no stream_start received from ingest")
    who = f"ins ({label or RUNS[prefix]})"
    counts, st = start["counts"], status["stream"]
    key = got.solution_keys[prefix]
    aids = status.get("aid_counts") or {}
    problems = [f"{what}: {n} of {want}" for what, n, want in
                ((f"IMU consumed by {who}", status["imu_count"], counts["imu"]),
                 (f"GNSS consumed by {who}", status["gnss_count"], counts["gnss"]),
                 *((f"{a} samples consumed by {who}", aids.get(a, 0), n) for a, n in counts.items()
                   if a not in ("imu", "gnss")),
                 (f"solutions of {who} received", len(sols), counts["imu"]),
                 (f"solutions of {who} recorded", recorded.get(key, 0), counts["imu"])) if n != want]
    problems += [f"{n} {what} ({who})" for what in ("gap", "duplicate") if (n := st.get(what, 0))]
    if [m["seq"] for m in sols] != list(range(len(sols))):
        problems.append(f"solution sequence numbers of {who} not contiguous")
    if problems:
        raise click.ClickException(f"the distributed run lost or duplicated samples: {'; '.join(problems)}")
    res = ReplayResult(
        dataset=start["dataset"],
        t_ns=np.array([m["t_ns"] for m in sols], dtype=np.int64),
        llh=np.array([m["llh"] for m in sols]),
        v_n=np.array([m["v_n"] for m in sols]),
        q_nb=np.array([m["q_nb"] for m in sols]),
        std_pos_ned=np.array([m["std_pos_ned"] for m in sols]),
        outage=np.array([m["gnss_state"] != "valid" for m in sols]),
        windows=[(int(a), int(b)) for a, b in start["outages"]],
        status={"gnss_state": status["gnss_state"], "counters": status["counters"]},
        wall_s=float(st["wall_s"]),
    )
    return Pipeline(res, status, recorded.get(key, 0))


def recording_stats(recording: Path) -> tuple[dict[str, int], int]:
    """Messages per key in the recording, and their total."""
    from mcap.reader import make_reader

    with open(recording, "rb") as f:
        summary = make_reader(f).get_summary()
    if summary is None or summary.statistics is None:
        raise click.ClickException(f"{recording} has no summary (the recorder did not finish it)")
    stats = summary.statistics
    per_key = {summary.channels[c].topic: n for c, n in stats.channel_message_counts.items()}
    return per_key, stats.message_count


def learning_over_the_bus(recording: Path, ins_status: dict) -> dict:
    """What the learning loop did over the bus, from the recording (the trainer's parameter sets, the
    predictor's answers and refusals) and the learning ins's final status (its side: queries, fused answers,
    rejections): the figures the demo prints and writes to metrics.json."""
    from .recording import read_mcap

    sets: list[dict] = []
    answers: Counter[int] = Counter()
    refused: Counter[str] = Counter()
    for key, msg, _payload, _t in read_mcap(recording, [r"/learn/model/", r"/learn/correction$"]):
        if msg is None:
            continue
        if "/learn/model/" in key:
            sets.append({"name": msg["name"], "version": int(msg["version"]),
                         "samples_seen": int(msg.get("metrics", {}).get("samples_seen", -1))})
        elif msg.get("refused"):
            refused[str(msg["refused"])] += 1
        else:
            answers[int(msg["version"])] += 1
    model = ins_status.get("model", {})
    counters = ins_status.get("counters", {})
    return {"sets_published": sets, "answers_by_version": {str(v): n for v, n in sorted(answers.items())},
            "answered": sum(answers.values()), "refused": dict(refused), "ins": model,
            "engine_rejections": {k: int(v) for k, v in counters.items()
                                  if k.startswith("learned_") and not k.endswith("_fused")}}


def _learning_lines(lo: dict) -> list[str]:
    sets = lo["sets_published"]
    ins = lo["ins"]
    versions = ", ".join(f"v{s['version']} through {s['samples_seen']} samples" for s in sets) or "none"
    used = ", ".join(f"v{v}: {n}" for v, n in lo["answers_by_version"].items()) or "none"
    refused = ", ".join(f"{r} {n}" for r, n in lo["refused"].items()) or "none"
    rejected = {k: v for k, v in ins.items() if k.startswith("refused_") or k in ("not_fused", "unanswered",
                                                                                   "unmatched", "mismatched")}
    return [f"  trainer   {len(sets)} parameter sets published: {versions}",
            f"  predictor {lo['answered']} queries answered (by set version: {used}); refused: {refused}; late "
            f"sets: {ins.get('lockstep_timeouts', 0)}",
            f"  ins       {ins.get('samples', 0)} training samples sent, {ins.get('queries', 0)} queries sent, "
            f"{ins.get('fused', 0)} answers fused; not fused: {rejected or 'none'}; engine rejections: "
            f"{lo['engine_rejections'] or 'none'}"]


def could_not_help(lo: dict, min_samples: int) -> str:
    """Why the learned run could not differ from the plain one ('' when some answer was fused); min_samples: the
    samples the trainer needs before its first fit."""
    ins = lo["ins"]
    if ins.get("fused", 0) > 0:
        return ""
    if not ins.get("queries", 0):
        return "the ins sent no query (no GNSS outage long enough, or learning off)"
    if not lo["sets_published"]:
        return (f"no model yet: the ins had sent {ins.get('samples', 0)} training samples when GNSS was lost, the "
                f"trainer fits from {min_samples} (a longer drive or a later outage helps)")
    if not lo["answered"]:
        return f"every query was refused ({', '.join(f'{r} {n}' for r, n in lo['refused'].items())})"
    return "no answer passed the ins's checks (see the rejections above)"


COMMON_ROWS = ("dataset", "duration", "IMU rate", "truth")  # the same for every run of one demo: printed once


def side_by_side(rows: dict[str, dict]) -> str:
    """The accuracy tables of several runs (label -> metrics dict) side by side, the rows they share first."""
    tables = {label: [line.split("  ", 1) for line in format_table(m).splitlines()] for label, m in rows.items()}
    first = next(iter(tables.values()))
    names = [r[0].rstrip() for r in first]
    cols = {label: [r[1].strip() if len(r) > 1 else "" for r in t] for label, t in tables.items()}
    width = max(len(n) for n in names)
    common = [f"{n:<{width}}  {cols[next(iter(cols))][i]}" for i, n in enumerate(names) if n in COMMON_ROWS]
    keep = [i for i, n in enumerate(names) if n not in COMMON_ROWS]
    widths = {label: max(len(label), *(len(col[i]) for i in keep)) for label, col in cols.items()}
    head = f"{'':<{width}}  " + "  ".join(f"{label:<{widths[label]}}" for label in cols)
    body = [f"{names[i]:<{width}}  " + "  ".join(f"{cols[label][i]:<{widths[label]}}" for label in cols)
            for i in keep]
    return "\n".join([*common, "", head.rstrip(), *(b.rstrip() for b in body)])


def _verdict(diff: dict) -> str:
    if not diff["same_epochs"]:
        return "DIFFERENT epochs"
    verdict = ("identical, bit for bit" if diff["bit_for_bit"] else "identical to 1e-9" if diff["identical"]
               else "DIFFERENT")
    return (f"max |difference| position {diff['position_m']:.3g} m, velocity {diff['velocity_mps']:.3g} m/s, "
            f"quaternion {diff['quaternion']:.3g}, position std {diff['std_pos_m']:.3g} m, GNSS state "
            f"{'same' if diff['gnss_state_same'] else 'DIFFERENT'}: {verdict}")


def compare(a: ReplayResult, b: ReplayResult) -> dict:
    """Largest differences between two solutions of the same epochs (position in metres)."""
    if not np.array_equal(a.t_ns, b.t_ns):
        return {"same_epochs": False, "identical": False}
    d = {"same_epochs": True,
         "position_m": float(np.linalg.norm(ned_errors(a.llh, b.llh), axis=1).max()),
         "llh": float(np.abs(a.llh - b.llh).max()),
         "velocity_mps": float(np.abs(a.v_n - b.v_n).max()),
         "quaternion": float(np.abs(a.q_nb - b.q_nb).max()),
         "std_pos_m": float(np.abs(a.std_pos_ned - b.std_pos_ned).max()),
         "gnss_state_same": bool(np.array_equal(a.outage, b.outage))}
    worst = max(d["llh"], d["velocity_mps"], d["quaternion"], d["std_pos_m"])
    d["bit_for_bit"] = d["gnss_state_same"] and worst == 0.0
    d["identical"] = d["gnss_state_same"] and worst <= 1e-9
    return d


def _horizontal_error(ds, res: ReplayResult, sel: np.ndarray) -> np.ndarray:
    """Horizontal error [m] of res at the truth epochs ``sel`` (as zennav.metrics.evaluate computes it)."""
    truth = ds.truth
    llh = antenna_llh(res.llh, res.q_nb, ds.config.lever_arm_b) if truth.at_antenna else res.llh
    x = (res.t_ns - res.t_ns[0]).astype(float)
    xq = (truth.t_ns[sel] - res.t_ns[0]).astype(float)
    est = np.column_stack([np.interp(xq, x, llh[:, i]) for i in range(3)])
    e = ned_errors(est, truth.llh[sel])
    return np.hypot(e[:, 0], e[:, 1])


def write_plots(out: Path, ds, runs: dict[str, ReplayResult], windows: list[tuple[float, float]] | None = None,
                window_name: str = "GNSS outage") -> list[Path]:
    """horizontal_error.png (error vs time, the windows shaded) and track.png (north/east, truth and solutions, and a
    zoom on the end of the last window, where the drift peaks). windows: [(start, end)] [s from the initial time],
    named window_name in the plots (default: the first run's GNSS outages)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    first = next(iter(runs.values()))
    t0 = int(ds.initial.t_ns)
    truth = ds.truth
    idx = np.flatnonzero((truth.t_ns >= first.t_ns[0]) & (truth.t_ns <= first.t_ns[-1]))
    idx = idx[:: max(1, len(idx) // 20_000)]
    t_s = (truth.t_ns[idx] - t0) / NS
    if windows is None:
        windows = [((a - t0) / NS, (b - t0) / NS) for a, b in first.windows]

    fig, ax = plt.subplots(figsize=(10, 4.5))
    for i, (a, b) in enumerate(windows):
        ax.axvspan(a, b, color="tab:red", alpha=0.15, label=window_name if i == 0 else None)
    for label, res in runs.items():
        ax.plot(t_s, _horizontal_error(ds, res, idx), lw=1, label=label)
    ax.set(xlabel="time from start [s]", ylabel="horizontal error [m]", title=f"{ds.name}: horizontal position error")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    paths = [out / "horizontal_error.png"]
    fig.savefig(paths[0], dpi=110)
    plt.close(fig)

    origin = np.repeat(truth.llh[idx[:1]], len(idx), axis=0)
    fig, axes = plt.subplots(1, 2, figsize=(13, 6.5))
    end = windows[-1][1] if windows else t_s[-1]
    zoom = (t_s >= end - 6.0) & (t_s <= end + 2.0)  # the end of the (last) window, where the drift peaks
    for ax, sel, title in ((axes[0], np.ones_like(zoom), "track"), (axes[1], zoom, f"end of the {window_name}")):
        ne = ned_errors(truth.llh[idx[sel]], origin[sel])
        ax.plot(ne[:, 1], ne[:, 0], "k-", lw=2.5, alpha=0.35, label="truth")
        for label, res in runs.items():
            k = np.clip(np.searchsorted(res.t_ns, truth.t_ns[idx[sel]]), 0, len(res.t_ns) - 1)
            ne = ned_errors(res.llh[k], origin[sel])
            ax.plot(ne[:, 1], ne[:, 0], lw=1, label=label)
        for i, (a, b) in enumerate(windows):
            inside = (t_s >= a) & (t_s < b) & sel
            ne = ned_errors(truth.llh[idx[inside]], origin[inside])
            ax.plot(ne[:, 1], ne[:, 0], color="tab:red", lw=5, alpha=0.25,
                    label=f"truth during {window_name}" if i == 0 else None)
        ax.set(xlabel="east [m]", ylabel="north [m]", title=f"{ds.name}: {title}")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.tight_layout()
    paths.append(out / "track.png")
    fig.savefig(paths[1], dpi=110)
    plt.close(fig)
    return paths


def run_demo(out: Path, spec: DemoSpec, launch_file: Path = DEMO_LAUNCH) -> None:
    """Everything `zennav demo` does (see the module docstring); raises click.ClickException on failure."""
    from .datasets.registry import load_dataset
    from .learn.loop import InProcessLoop
    from .learn.settings import compensation_settings
    from .params import load_filter_params, nav_config

    wall0 = time.monotonic()
    out = out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    ds = load_dataset(spec.dataset, **spec.options)
    ds.config = nav_config(ds.config, load_filter_params(None))  # the ins's filter (deploy/ins.yaml)
    settings = compensation_settings(spec.compensation, spec.seed)
    duration_s = (run_end_ns(ds) - int(ds.initial.t_ns)) / NS
    windows = ", ".join(f"{s:g}..{s + d:g} s" for s, d in spec.outages)
    if spec.every:
        windows = ", ".join(filter(None, [windows, f"{spec.every[1]:g} s every {spec.every[0]:g} s from "
                                                   f"{spec.every[2]:g} s"]))
    click.echo(f"zennav demo: {ds.name} ({duration_s:.0f} s), GNSS withheld {windows or 'never'}; learning loop "
               f"over the bus: {settings.label} on the {TARGET} target, seed {settings.seed}\n")

    def in_process():
        loop = InProcessLoop(TARGET, settings)
        return (run_replay(ds, outages=spec.outages, outage_every=spec.every, smoothing=True),
                run_replay(ds, outages=spec.outages, outage_every=spec.every, compensator=loop))

    in_process_result = _background(in_process)
    recording, got = run_set(launch_file, out, spec, settings, limit_s=2.0 * duration_s + 300.0)
    recorded, n_recorded = recording_stats(recording)
    pipes = {p: pipeline_result(got, p, recorded) for p in RUNS}
    start = got.start
    assert start is not None  # pipeline_result raised without one
    learned, plain = pipes[""], pipes[PLAIN_PREFIX]
    ref_plain, ref_learned = in_process_result()
    diffs = {"no_learning": compare(plain.result, ref_plain), "learned": compare(learned.result, ref_learned)}
    lo = learning_over_the_bus(recording, learned.status)

    for p, pipe in pipes.items():
        st = pipe.status
        click.echo(f"\nins ({RUNS[p]}) consumed {st['imu_count']}/{start['counts']['imu']} IMU and "
                   f"{st['gnss_count']}/{start['counts']['gnss']} GNSS samples over Zenoh in "
                   f"{pipe.result.wall_s:.1f} s ({st['imu_count'] / max(pipe.result.wall_s, 1e-9):.0f} IMU/s): "
                   "none lost or duplicated")
    n = len(plain.result.t_ns)
    click.echo(f"no learning, distributed vs in-process replay, {n} epochs: {_verdict(diffs['no_learning'])}")
    click.echo(f"learned, distributed (lockstep) vs in-process learning loop, {n} epochs: "
               f"{_verdict(diffs['learned'])}")
    click.echo(f"\nlearning loop over the bus ({settings.label}, {TARGET}):")
    click.echo("\n".join(_learning_lines(lo)))
    assert settings.min_samples is not None  # LearnSettings.__post_init__ resolves it (None: the model's default)
    why = could_not_help(lo, settings.min_samples)

    m_plain, m_learned = evaluate(ds, plain.result), evaluate(ds, learned.result)
    for m, label in ((m_plain, "none"), (m_learned, settings.label)):
        m["compensation"] = {"model": label, "target": TARGET if label != "none" else None, "seed": settings.seed,
                             "where": "over the bus (trainer, predictor and ins services)"}
    m_learned["pipeline"] = {"launch_file": str(launch_file), "recording": str(recording),
                             "recorded_messages": n_recorded, "ins_status": learned.status,
                             "vs_in_process": diffs["learned"], "learning": lo, "could_not_help": why}
    m_plain["pipeline"] = {"launch_file": str(launch_file), "recording": str(recording),
                           "ins_status": plain.status, "vs_in_process": diffs["no_learning"]}
    plain_dir = out / "no-learning"
    write_outputs(out, ds, learned.result, m_learned)
    write_outputs(plain_dir, ds, plain.result, m_plain)
    assert ref_plain.smoothed is not None  # run with smoothing
    plots = write_plots(out, ds, {"no learning (over the bus)": plain.result,
                                  f"learned {settings.label} (over the bus)": learned.result,
                                  "no learning, smoothed (in-process post-processing)": ref_plain.smoothed})

    click.echo("\nAccuracy against the truth, both measured over the bus:")
    click.echo(side_by_side({"no learning": m_plain, f"learned ({settings.label}, {TARGET})": m_learned}))
    if why:
        click.echo(f"\nLEARNING COULD NOT HELP in this run: {why}; the learned row equals the unlearned one.")
    click.echo(f"\nrecording  {recording} ({n_recorded} messages on {len(recorded)} keys; opens in Foxglove)"
               f"\nlearned    {out / 'nav.txt'}, nav.csv, metrics.json"
               f"\nno learning {plain_dir / 'nav.txt'}, nav.csv, metrics.json"
               f"\nplots      {plots[0]}, {plots[1].name}"
               f"\nlog        {out / 'launch.log'}"
               f"\ndone in {time.monotonic() - wall0:.0f} s")
    bad = [what for what, d in diffs.items() if not d["identical"]]
    if bad:
        raise click.ClickException(f"the distributed solution differs from the in-process replay ({', '.join(bad)})")
