"""`zennav demo`: the whole process set on loopback over the built-in simulated drive, scored against its truth.

1. Launches deploy/demo.yaml (router, ins, attitude, predictor, trainer, monitor, record, ingest) on a free
   loopback port with zennav.launch; ingest streams sim:car as fast as the pipeline drains without loss and
   ``zennav record`` writes the vehicle's whole key space to MCAP; the demo process subscribes to the
   navigation solution itself. Meanwhile a thread runs the same drive in process: the plain replay and the
   replay with in-process learned compensation (ANFIS, body-velocity target).
2. Checks that no sample was lost or duplicated (ins counters, solution sequence, the recording's count)
   and that the distributed solution equals the in-process replay, scores both with zennav.metrics, writes
   nav.txt, nav.csv, metrics.json and PNG plots, and prints the tables and the paths.

Any service that fails, a set that does not come up, or a run that outlasts its time limit stops every
process and raises click.ClickException (exit code 1) with the tail of the services' log.
"""
from __future__ import annotations

import os
import signal
import socket
import threading
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import click
import numpy as np

from .launch import Launcher, load_launch
from .metrics import antenna_llh, evaluate, format_table, ned_errors, write_outputs
from .nav.types import NS
from .replay import ReplayResult, run_replay

DEMO_LAUNCH = Path(__file__).resolve().parents[2] / "deploy" / "demo.yaml"
LEARNED = ("anfis", "body_velocity")  # the in-process learned compensation the demo scores


@dataclass
class Pipeline:
    """What the distributed run produced: the solution as a ReplayResult, the ins's final nav_status
    message, the expected sample counts and the recording's message statistics."""

    result: ReplayResult
    status: dict
    counts: dict
    recorded: int
    recorded_keys: int


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _set_arg(cmd: list, flag: str, value: str, service: str) -> None:
    """Replace the value that follows ``flag`` in a launch-file command."""
    try:
        cmd[cmd.index(flag) + 1] = value
    except (ValueError, IndexError):
        raise click.ClickException(f"the launch file's {service} command has no '{flag} VALUE' to set") from None


class _Tee:
    """The launcher's output: every line to the log file; the launcher's own lines and the services'
    warnings and errors also to the terminal."""

    def __init__(self, f):
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
    every navigation solution and the ins's end-of-stream status; ``complete`` is set once all are in."""

    def __init__(self, bus):
        self.start: dict | None = None
        self.status: dict | None = None
        self.solutions: list[dict] = []
        self.complete = threading.Event()
        k = bus.keys
        self.solution_key = k.nav_solution()
        bus.subscribe(k.stream(), self._on_stream, channel="fifo", name="demo-stream")
        bus.subscribe(k.nav_solution(), self._on_solution, channel="fifo", capacity=65536, name="demo-solution")
        bus.subscribe(k.nav_status(), self._on_status, channel="fifo", name="demo-status")

    def _on_stream(self, key, msg, recv_ns) -> None:
        if msg["schema"] == "stream_start":
            self.start = msg

    def _on_solution(self, key, msg, recv_ns) -> None:
        self.solutions.append(msg)
        self._check()

    def _on_status(self, key, msg, recv_ns) -> None:
        if msg["stream"].get("done"):
            self.status = msg
            self._check()

    def _check(self) -> None:
        if self.status is not None and len(self.solutions) >= self.status["stream"]["solutions"]:
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
        self.failed = [f"{c.spec.name} exited with code {c.proc.returncode}" for c in self.children.values()
                       if c.finished and c.proc.returncode != 0]
        if not self.failed and time.monotonic() > self.deadline:
            self.failed = [f"the stream did not finish within {self.limit_s:.0f} s"]
        self.completed = not self.failed and self.children["record"].finished and self.complete.is_set()
        return self.completed or bool(self.failed)


def _background(fn):
    """Run fn in a daemon thread; the returned callable joins it and returns its result (or raises)."""
    box: dict = {}

    def run():
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


def run_set(launch_file: Path, out: Path, duration_s: float, outage: tuple[float, float]) -> tuple[Path, _Collector]:
    """Launch the process set until the recorder and the demo have every solution; returns the recording's
    path and what the demo received."""
    from .bus import Bus

    if not launch_file.is_file():
        raise click.ClickException(f"{launch_file} not found (it ships in the source tree's deploy/; "
                                   "or give --launch-file)")
    recording = out / "demo.mcap"
    recording.unlink(missing_ok=True)
    spec = load_launch(launch_file, {"rendezvous": f"tcp/127.0.0.1:{free_port()}"})
    svc = {s.name: s for s in spec.services}
    for need in ("record", "ingest"):
        if need not in svc:
            raise click.ClickException(f"{launch_file} has no '{need}' service")
    _set_arg(svc["record"].command, "--", str(recording), "record")
    _set_arg(svc["ingest"].command, "-o", f"duration_s={float(duration_s)!r}", "ingest")
    _set_arg(svc["ingest"].command, "--outage", f"{outage[0]!r}:{outage[1]!r}", "ingest")
    for k in ("ZENNAV_LISTEN", "ZENNAV_ZENOH_CONFIG"):  # the set's own loopback endpoints and configs only
        os.environ.pop(k, None)
    log = out / "launch.log"
    click.echo(f"process set {launch_file} ({len(spec.services)} processes), rendezvous {spec.rendezvous}, "
               f"multicast scouting off; full log: {log}")
    bus = Bus(f"demo-{os.getpid()}", spec.vehicle, mode="peer", connect=[spec.rendezvous],
              listen=["tcp/127.0.0.1:0"], token=False)
    collector = _Collector(bus)
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    with open(log, "w") as f:
        tee = _Tee(f)
        launcher = _DemoLauncher(spec, tee, bus, collector.complete, limit_s=spec.up_timeout_s + duration_s)
        try:
            rc = launcher.run()
        finally:
            for s, h in handlers.items():
                signal.signal(s, h)
            bus.close()
    if launcher.completed:
        return recording, collector
    if rc == 0 and not launcher.failed:
        raise click.Abort()  # Ctrl-C: every process was stopped
    click.echo("\n".join(["", f"last lines of {log}:", *tee.tail]), err=True)
    said = [line.split("] ", 1)[1] for line in tee.tail if line.startswith("[launch") and
            ("timeout" in line or "error:" in line)]
    why = "; ".join(launcher.failed or said[-1:]) or "the process set did not come up"
    raise click.ClickException(f"demo failed: {why} (every process was stopped; full log: {log})")


def pipeline_result(recording: Path, got: _Collector) -> Pipeline:
    """The distributed solution as a ReplayResult, checked: nothing lost or duplicated between ingest, ins,
    the demo and the recording; raises ClickException otherwise."""
    from mcap.reader import make_reader

    start, status, sols = got.start, got.status, got.solutions
    if start is None:
        raise click.ClickException("no stream_start received from ingest")
    with open(recording, "rb") as f:
        summary = make_reader(f).get_summary()
    stats = summary.statistics
    recorded = {summary.channels[c].topic: n for c, n in stats.channel_message_counts.items()}
    counts, st = start["counts"], status["stream"]
    problems = [f"{what}: {n} of {want}" for what, n, want in
                (("IMU consumed by ins", status["imu_count"], counts["imu"]),
                 ("GNSS consumed by ins", status["gnss_count"], counts["gnss"]),
                 ("solutions received", len(sols), counts["imu"]),
                 ("solutions recorded", recorded.get(got.solution_key, 0), counts["imu"])) if n != want]
    problems += [f"{n} {what}" for what in ("gap", "duplicate") if (n := st.get(what, 0))]
    if [m["seq"] for m in sols] != list(range(len(sols))):
        problems.append("solution sequence numbers not contiguous")
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
    return Pipeline(res, status, counts, stats.message_count, len(recorded))


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


def write_plots(out: Path, ds, runs: dict[str, ReplayResult]) -> list[Path]:
    """horizontal_error.png (error vs time, outages shaded) and track.png (north/east, truth and solutions)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    first = next(iter(runs.values()))
    t0 = int(ds.initial.t_ns)
    truth = ds.truth
    idx = np.flatnonzero((truth.t_ns >= first.t_ns[0]) & (truth.t_ns <= first.t_ns[-1]))
    idx = idx[:: max(1, len(idx) // 20_000)]
    t_s = (truth.t_ns[idx] - t0) / NS
    windows = [((a - t0) / NS, (b - t0) / NS) for a, b in first.windows]

    fig, ax = plt.subplots(figsize=(10, 4.5))
    for i, (a, b) in enumerate(windows):
        ax.axvspan(a, b, color="tab:red", alpha=0.15, label="GNSS outage" if i == 0 else None)
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
    zoom = (t_s >= end - 6.0) & (t_s <= end + 2.0)  # the end of the (last) outage, where the drift peaks
    for ax, sel, title in ((axes[0], np.ones_like(zoom), "track"), (axes[1], zoom, "end of the GNSS outage")):
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
                    label="truth during GNSS outage" if i == 0 else None)
        ax.set(xlabel="east [m]", ylabel="north [m]", title=f"{ds.name}: {title}")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.tight_layout()
    paths.append(out / "track.png")
    fig.savefig(paths[1], dpi=110)
    plt.close(fig)
    return paths


def run_demo(out: Path, duration_s: float, outage: tuple[float, float], launch_file: Path = DEMO_LAUNCH) -> None:
    """Everything `zennav demo` does (see the module docstring); raises click.ClickException on failure."""
    from .learn.loop import make_compensator
    from .datasets.registry import load_dataset

    wall0 = time.monotonic()
    out = out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    ds = load_dataset("sim:car", duration_s=float(duration_s))
    outages = [outage]
    click.echo(f"zennav demo: simulated car drive ({ds.name}, {duration_s:g} s, 200 Hz IMU, 1 Hz GNSS), GNSS "
               f"withheld {outage[0]:g}..{outage[0] + outage[1]:g} s\n")
    in_process = _background(lambda: (run_replay(ds, outages=outages),
                                       run_replay(ds, outages=outages, compensator=make_compensator(*LEARNED))))
    recording, got = run_set(launch_file, out, duration_s, outage)
    pipe = pipeline_result(recording, got)
    dist = pipe.result
    ref, learned = in_process()

    st = pipe.status
    diff = compare(dist, ref)
    click.echo(f"\nins consumed {st['imu_count']}/{pipe.counts['imu']} IMU and {st['gnss_count']}/"
               f"{pipe.counts['gnss']} GNSS samples over Zenoh in {dist.wall_s:.1f} s "
               f"({st['imu_count'] / max(dist.wall_s, 1e-9):.0f} IMU/s): none lost or duplicated")
    if diff["same_epochs"]:
        verdict = ("identical, bit for bit" if diff["bit_for_bit"] else "identical to 1e-9" if diff["identical"]
                   else "DIFFERENT")
        click.echo(f"distributed vs in-process replay, {len(dist.t_ns)} epochs: max |difference| position "
                   f"{diff['position_m']:.3g} m, velocity {diff['velocity_mps']:.3g} m/s, quaternion "
                   f"{diff['quaternion']:.3g}, position std {diff['std_pos_m']:.3g} m, GNSS state "
                   f"{'same' if diff['gnss_state_same'] else 'DIFFERENT'}: {verdict}")
    else:
        click.echo(f"distributed vs in-process replay: DIFFERENT epochs ({len(dist.t_ns)} vs {len(ref.t_ns)})")

    m_dist = evaluate(ds, dist)
    m_dist["compensation"] = {"model": "none", "target": None}
    m_dist["pipeline"] = {"launch_file": str(launch_file), "recording": str(recording),
                          "recorded_messages": pipe.recorded, "ins_status": st, "vs_in_process": diff}
    m_learned = evaluate(ds, learned)
    m_learned["compensation"] = {"model": LEARNED[0], "target": LEARNED[1], "where": "in-process"}
    learned_dir = out / f"learned-{LEARNED[0]}-inprocess"
    write_outputs(out, ds, dist, m_dist)
    write_outputs(learned_dir, ds, learned, m_learned)
    plots = write_plots(out, ds, {"distributed, no compensation": dist,
                                  f"learned {LEARNED[0]} ({LEARNED[1]}), in-process": learned})

    click.echo("\nAccuracy, distributed pipeline (ingest -> ins over Zenoh), no learned compensation:")
    click.echo(format_table(m_dist))
    click.echo(f"\nAccuracy with learned compensation ({LEARNED[0]}, {LEARNED[1]} target), IN-PROCESS replay "
               "(zennav.compensation in this process, not the trainer/predictor services):")
    click.echo(format_table(m_learned))
    click.echo(f"\nrecording  {recording} ({pipe.recorded} messages on {pipe.recorded_keys} keys; opens in Foxglove)"
               f"\nsolution   {out / 'nav.txt'}, nav.csv, metrics.json"
               f"\nlearned    {learned_dir / 'nav.txt'}, nav.csv, metrics.json"
               f"\nplots      {plots[0]}, {plots[1].name}"
               f"\nlog        {out / 'launch.log'}"
               f"\ndone in {time.monotonic() - wall0:.0f} s")
    if not diff["identical"]:
        raise click.ClickException("the distributed solution differs from the in-process replay")
