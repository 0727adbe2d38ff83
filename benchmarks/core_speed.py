"""Speed of the navigation core, side by side in one run (issue 17's figures; medians of --repeats runs).

- loop: run_replay over a simulated car drive (--minutes at 200 Hz, 1 Hz GNSS, a 60 s outage in the middle), the
  engine only (no file I/O): compiled block loop (zennav.nav.kernels via Navigator.run_imu) and step by step
  (on_imu, the services' Python path); CPU seconds of this process and real-time factors, and the largest
  difference between the two solutions;
- command: ``zennav replay`` as a whole command (start-up, reading the KF-GINS text files, writing nav.txt, nav.csv,
  metrics) on the same drive written as KF-GINS files, by default (compiled from JIT_MIN_S of data on) and with
  ZENNAV_JIT=0; wall and CPU seconds of the child process; with --baseline, another checkout's command alternately
  with the default (the same files, the same minutes);
- learning: ``zennav replay sim:car --compensation anfis|elman`` (default target) over --learn-minutes, whole
  command;
- pyins (``python-ins``, a Python INS with numba, bench extra) on the first --pyins-minutes of the same drive: its
  feedback filter (run_feedback_filter, position fixes), CPU seconds and real-time factor;
- KF-GINS (--kf-gins PATH, the binary) on the same KF-GINS files, wall and CPU seconds;
- --profile stages: where one whole command's time goes (a child ``zennav replay`` on the KF-GINS files with its
  stages timed from inside: imports, loading, the step-wise samples (the head of the IMU file and the GNSS epochs),
  waiting for the rest of the IMU file, loading numba, the compiled stretches, waiting for the truth, the metrics,
  the files; CPU: the process's, all threads), and the reads in the reader thread beside them (the rest of the IMU
  file, the truth: wall and that thread's CPU).

    .venv/bin/python benchmarks/core_speed.py [--minutes 30] [--repeats 3] [--learn-minutes 30] [--kf-gins PATH]
        [--baseline OTHER/.venv/bin/zennav] [--profile loop|command|stages]
"""
from __future__ import annotations

import argparse
import cProfile
import logging
import os
import pstats
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from zennav.datasets import kfgins
from zennav.nav.types import NS
from zennav.replay import run_replay
from zennav.sim.scenarios import make_dataset

ZENNAV = str(Path(sys.executable).parent / "zennav")

# --profile stages: a whole `zennav replay` (argv after -c) with the wall and CPU seconds of its stages, on stderr
STAGES = r"""
import resource, sys, time
def cpu():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime
w0, c0 = time.perf_counter(), cpu()
import zennav.datasets.kfgins as KF, zennav.datasets.registry as REG, zennav.datasets.streamed as ST
import zennav.metrics as MT, zennav.nav.kernels as KN, zennav.nav.navigator as NV, zennav.replay as RP
import zennav.replay_cli, zennav.run_outputs as RO
rows = [("imports (zennav, numpy, click)", time.perf_counter() - w0, cpu() - c0, 1)]
acc = {}
def timed(owner, name, label):
    f = getattr(owner, name)
    def g(*a, **k):
        w, c = time.perf_counter(), cpu()
        try:
            return f(*a, **k)
        finally:
            d = acc.setdefault(label, [0.0, 0.0, 0])
            d[0] += time.perf_counter() - w; d[1] += cpu() - c; d[2] += 1
    setattr(owner, name, g)
def reader(owner):  # the reads in the reader thread (beside the run): their wall and their thread's CPU seconds
    f = owner.in_background
    def g(read):
        def timed_read():
            w, c = time.perf_counter(), time.thread_time()
            try:
                return read()
            finally:
                d = acc.setdefault("reader thread (IMU rest, truth; beside)", [0.0, 0.0, 0])
                d[0] += time.perf_counter() - w; d[1] += time.thread_time() - c; d[2] += 1
        return f(timed_read)
    owner.in_background = g
reader(ST), reader(KF)
for owner, name, label in ((REG, "load_dataset", "load dataset (IMU head, GNSS)"),
                           (NV.Navigator, "on_imu", "step-wise samples (head, GNSS epochs)"),
                           (ST.StreamedImu, "whole", "wait for the rest of the IMU file"),
                           (KN, "compiled", "load numba and the kernels"),
                           (NV.Navigator, "run_imu", "compiled stretches"),
                           (KF, "load_deferred_truth", "wait for the truth file"), (MT, "evaluate", "metrics"),
                           (KF, "write_nav", "write nav.txt"), (MT, "write_solution", "write nav.txt + nav.csv"),
                           (RO.RunRecorder, "write", "write aid.csv, biases.csv, run.json")):
    timed(owner, name, label)
sys.argv = ["zennav", "replay", *sys.argv[1:]]
from zennav.cli import main
try:
    main()
except SystemExit:
    pass
rows += [(k, *v) for k, v in acc.items()] + [("whole command (from the imports on)",
                                              time.perf_counter() - w0, cpu() - c0, 1)]
sys.stderr.write("".join(f"STAGE {k}\t{w}\t{c}\t{n}\n" for k, w, c, n in rows))
"""


def stages(cmd_args: list[str]) -> None:
    """Print where the wall and CPU seconds of one whole ``zennav replay cmd_args`` go (STAGES, in a child)."""
    r = subprocess.run([sys.executable, "-c", STAGES, *cmd_args], check=True, stdout=subprocess.DEVNULL,
                       stderr=subprocess.PIPE, text=True)
    print(f"{'stages of one whole command':<44}{'wall s':>9}{'CPU s':>9}{'calls':>8}")
    for ln in r.stderr.splitlines():
        if ln.startswith("STAGE "):
            name, wall, cpu, n = ln[6:].split("\t")
            print(f"  {name:<42}{float(wall):9.2f}{float(cpu):9.2f}{int(n):8d}")


def cpu_of(fn, *args, **kw):
    """(result, CPU seconds of this process) of fn(*args, **kw)."""
    c0 = time.process_time()
    res = fn(*args, **kw)
    return res, time.process_time() - c0


def child(cmd: list[str], env: dict | None = None, cwd: str | None = None) -> tuple[float, float]:
    """(wall, CPU) seconds of a child process (CPU: user + system of the children, from getrusage)."""
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    w0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, env={**os.environ, **(env or {})}, cwd=cwd)
    wall = time.perf_counter() - w0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)


def median_pair(runs):
    return statistics.median(r[0] for r in runs), statistics.median(r[1] for r in runs)


def line(name: str, data_s: float, wall: float | None, cpu: float, note: str = "") -> None:
    w = f"{wall:9.2f}{data_s / wall:10.0f}x" if wall is not None else f"{'':9}{'':11}"
    print(f"{name:<44}{w}{cpu:9.2f}{data_s / cpu:10.0f}x  {note}")


def pyins_run(ds, seconds: float) -> tuple[float, float]:
    """CPU seconds of pyins's feedback filter over the first `seconds` of ds (position fixes of 0.5 m), and its
    horizontal RMS error [m] against the truth."""
    import pandas as pd
    from pyins import filters, measurements

    from zennav.nav import earth

    t0 = int(ds.initial.t_ns)
    imu = ds.imu.slice((ds.imu.t_ns > t0) & (ds.imu.t_ns <= t0 + int(seconds * NS)))
    t = (imu.t_ns - t0) / NS
    inc = pd.DataFrame({"dt": np.diff(np.concatenate([[0.0], t]))}, index=t)
    for i, ax in enumerate("xyz"):
        inc[f"theta_{ax}"] = imu.dtheta[:, i]
        inc[f"dv_{ax}"] = imu.dvel[:, i]
    g = ds.gnss.slice((ds.gnss.t_ns > t0) & (ds.gnss.t_ns <= imu.t_ns[-1]))
    pos = pd.DataFrame({"lat": np.degrees(g.llh[:, 0]), "lon": np.degrees(g.llh[:, 1]), "alt": g.llh[:, 2]},
                       index=(g.t_ns - t0) / NS)
    init = ds.initial
    pva = pd.Series({"lat": np.degrees(init.llh[0]), "lon": np.degrees(init.llh[1]), "alt": init.llh[2],
                     "VN": init.v_n[0], "VE": init.v_n[1], "VD": init.v_n[2], "roll": np.degrees(init.euler[0]),
                     "pitch": np.degrees(init.euler[1]), "heading": np.degrees(init.euler[2])}, name=0.0)
    meas = [measurements.Position(pos, 0.5, np.asarray(ds.config.lever_arm_b))]
    res, cpu = cpu_of(filters.run_feedback_filter, pva, 1.0, 0.1, 1.0, 1.0, inc, measurements=meas, time_step=0.05)
    traj = res.trajectory
    tt = t0 + (np.asarray(traj.index) * NS).astype(np.int64)
    truth = np.column_stack([np.interp(tt, ds.truth.t_ns, ds.truth.llh[:, i]) for i in range(3)])
    est = np.column_stack([np.radians(traj.lat), np.radians(traj.lon), traj.alt])
    d = earth.llh_to_ned(est, truth[0]) - earth.llh_to_ned(truth, truth[0])
    return cpu, float(np.sqrt(np.mean(d[:, 0] ** 2 + d[:, 1] ** 2)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--minutes", type=float, default=30.0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--learn-minutes", type=float, default=30.0,
                    help="drive of the learning runs (0: skip; 30: the issue's 30-min drive)")
    ap.add_argument("--pyins-minutes", type=float, default=2.0, help="pyins's share of the drive (0: skip)")
    ap.add_argument("--kf-gins", type=Path, default=None, help="a KF-GINS binary to run on the same files")
    ap.add_argument("--baseline", type=Path, default=None,
                    help="another checkout's zennav console script (e.g. main's .venv/bin/zennav): its whole command "
                         "runs alternately with this one's on the same files")
    ap.add_argument("--profile", choices=("loop", "command", "stages"), default=None,
                    help="print the top of a cProfile of one compiled loop, or of one whole command in-process, or "
                         "the stages of one whole command (a child process)")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)  # the engine's outage warnings

    data_s = args.minutes * 60.0
    ds = make_dataset("car", duration_s=data_s, imu_rate_hz=200.0, gnss_rate_hz=1.0, seed=0)
    outages = [(data_s / 2, 60.0)]
    print(f"simulated car, {args.minutes:g} min, 200 Hz IMU, 1 Hz GNSS, 60 s outage at {data_s / 2:g} s; medians of "
          f"{args.repeats} runs; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print(f"{'':44}{'wall s':>9}{'real-time':>11}{'CPU s':>9}{'real-time':>11}")
    run_replay(ds, outages=outages, loop="compiled")  # compiles the kernels where their cache is empty
    loops = {}
    for loop in ("compiled", "step"):
        runs = []
        for _ in range(args.repeats):
            res, cpu = cpu_of(run_replay, ds, outages=outages, loop=loop)
            runs.append((res.wall_s, cpu))
            loops[loop] = res
        wall, cpu = median_pair(runs)
        line(f"loop, {loop} (target >= 3000x)" if loop == "compiled" else "loop, step by step (services' path)",
             data_s, wall, cpu)
    a, b = loops["compiled"], loops["step"]
    diff = max(float(np.max(np.abs(x - y) / np.maximum(np.abs(y), 1e-300))) for x, y in
               ((a.llh, b.llh), (a.v_n, b.v_n), (a.q_nb, b.q_nb), (a.std_pos_ned, b.std_pos_ned)))
    print(f"{'':44}compiled vs step: largest relative difference {diff:.1e}")

    with tempfile.TemporaryDirectory(prefix="core_speed_") as tmp:
        yaml_path = kfgins.write_dataset(ds, Path(tmp) / "files", "car")
        cmd = ["replay", str(yaml_path), "--outage", f"{data_s / 2:g}:60", "--out", str(Path(tmp) / "out"), "-q"]
        if args.baseline is not None:  # the two commands alternately, in the same minutes
            pairs = [(child([ZENNAV, *cmd]), child([str(args.baseline), *cmd])) for _ in range(args.repeats)]
            for k, name in enumerate(("command, default (target >= 500x)", "command, --baseline")):
                wall, cpu = median_pair([p[k] for p in pairs])
                line(name, data_s, wall, cpu, "KF-GINS text files in, nav.txt/nav.csv out" if k == 0 else
                     str(args.baseline))
        for name, env in (() if args.baseline is not None else (("command, default (target >= 500x)", {}),)) + \
                (("command, ZENNAV_JIT=0", {"ZENNAV_JIT": "0"}),):
            wall, cpu = median_pair([child([ZENNAV, *cmd], env) for _ in range(args.repeats)])
            line(name, data_s, wall, cpu, "KF-GINS text files in, nav.txt/nav.csv out")
        if args.kf_gins is not None:
            wall, cpu = median_pair([child([str(args.kf_gins), str(yaml_path)], cwd=str(Path(tmp) / "files"))
                                     for _ in range(args.repeats)])
            line("KF-GINS (C++), same files, no outage", data_s, wall, cpu)
        if args.profile == "stages":
            stages([str(yaml_path), "--outage", f"{data_s / 2:g}:60", "--out", str(Path(tmp) / "out"), "-q"])
        if args.profile == "command":
            from zennav.replay_cli import replay_dataset

            prof = cProfile.Profile()
            prof.runcall(replay_dataset, str(yaml_path), outages, None, Path(tmp) / "prof", False, quiet=True)
            pstats.Stats(prof).sort_stats("tottime").print_stats(15)

    if args.learn_minutes > 0:
        learn_s = args.learn_minutes * 60.0
        for model in ("anfis", "elman"):
            cmd = [ZENNAV, "replay", "sim:car", "-o", f"duration_s={learn_s:g}", "--outage", f"{learn_s / 2:g}:60",
                   "--compensation", model, "-q"]
            wall, cpu = median_pair([child(cmd) for _ in range(args.repeats)])
            line(f"learning, {model} (target >= 300x)", learn_s, wall, cpu, f"{args.learn_minutes:g} min sim:car")

    if args.pyins_minutes > 0:
        try:
            import pyins  # noqa: F401
        except ImportError:
            print("pyins (python-ins) not installed: pip install -e '.[bench]'")
        else:
            cpu, rms = pyins_run(ds, args.pyins_minutes * 60.0)
            line("pyins feedback filter, step 0.05 s", args.pyins_minutes * 60.0, None, cpu,
                 f"first {args.pyins_minutes:g} min, horizontal RMS {rms:.2f} m")

    if args.profile == "loop":
        prof = cProfile.Profile()
        prof.runcall(run_replay, ds, outages=outages, loop="compiled")
        pstats.Stats(prof).sort_stats("tottime").print_stats(15)


if __name__ == "__main__":
    main()
