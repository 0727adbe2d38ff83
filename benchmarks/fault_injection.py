"""Fault injection on the demo's process set: kill -9 of one service mid-drive, and what the run still delivers.

Usage (from the repository root):
    .venv/bin/python benchmarks/fault_injection.py                       # the 600 s drive, kills at 150 s
    .venv/bin/python benchmarks/fault_injection.py --duration 200 --kill-at 50 --outage 100:30

Each case runs `zennav demo`'s process set (deploy/demo.yaml: router, learning ins in lockstep, plain ins,
attitude, trainer, predictor, monitor, recorder, ingest as fast as it drains; zennav.demo.run_set, the demo's own
code path) over the simulated car drive with its GNSS outage. ``clean`` kills nothing; ``ins``, ``ins-plain``,
``predictor`` and ``router`` send SIGKILL to that service once the learned ins has published a solution --kill-at
seconds into the drive; the launcher restarts it (restart: on-failure) and the set recovers (zennav.checkpoint;
the learned ins, in lockstep, from the ingest's cache through zenoh's history; the plain ins from the ingest's
history by its backfill, zennav.stream.Backfill; recovering subscribers). Per case and ins (learned, plain):
samples navigated (distinct solution times, of the stream's IMU samples), data seconds without a solution, the
final horizontal error and the largest horizontal error in the outage (zennav.metrics against the simulator's
truth), each beside the clean run's; and the wall seconds from the kill until the service was back (liveliness).
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
import time
import traceback
from pathlib import Path

import numpy as np

from zennav.datasets.registry import load_dataset
from zennav.demo import DEMO_LAUNCH, RUNS, DemoSpec, _horizontal_error, run_set
from zennav.learn.settings import compensation_settings
from zennav.metrics import evaluate
from zennav.nav.types import NS
from zennav.params import load_filter_params, nav_config
from zennav.replay import ReplayResult, parse_outage

CASES = ("clean", "ins", "ins-plain", "predictor", "router")


def killer(case: str, kill_at_s: float, log: dict):
    """during(launcher, collector) for run_set: SIGKILL of service ``case`` once the learned ins's solution
    reaches kill_at_s of the drive; notes the kill and the service's return (liveliness) in log."""
    def during(launcher, collector) -> None:
        while collector.start is None or not collector.solutions[""] or \
                (collector.solutions[""][-1]["t_ns"] - collector.start["t_ns"]) / NS < kill_at_s:
            if launcher._stop.is_set():
                return
            time.sleep(0.02)
        child = launcher.children[case]
        proc = child.proc
        assert proc is not None  # the set is up: every service started
        os.kill(proc.pid, signal.SIGKILL)
        log["killed_wall"] = time.monotonic()
        log["killed_at_s"] = (collector.solutions[""][-1]["t_ns"] - collector.start["t_ns"]) / NS
        name = child.spec.alive_name
        while name in launcher.alive or child.proc is proc:  # gone, then restarted
            time.sleep(0.01)
        while name not in launcher.alive and not launcher._stop.is_set():
            time.sleep(0.01)
        log["back_s"] = time.monotonic() - log["killed_wall"]
    return during


def result_of(collector, prefix: str) -> tuple[ReplayResult, int]:
    """The distinct solutions of one ins (a resumed ins publishes those since its checkpoint twice) as a
    ReplayResult, and the number of IMU samples the stream had."""
    start = collector.start
    by_t = {m["t_ns"]: m for m in collector.solutions[prefix]}
    sols = [by_t[t] for t in sorted(by_t)]
    res = ReplayResult(dataset=start["dataset"], t_ns=np.array([m["t_ns"] for m in sols], dtype=np.int64),
                       llh=np.array([m["llh"] for m in sols]), v_n=np.array([m["v_n"] for m in sols]),
                       q_nb=np.array([m["q_nb"] for m in sols]),
                       std_pos_ned=np.array([m["std_pos_ned"] for m in sols]),
                       outage=np.array([m["gnss_state"] != "valid" for m in sols]),
                       windows=[(int(a), int(b)) for a, b in start["outages"]], status={}, wall_s=0.0)
    return res, int(start["counts"]["imu"])


def score(ds, res: ReplayResult, n_imu: int) -> dict:
    m = evaluate(ds, res)
    sel = np.flatnonzero((ds.truth.t_ns >= res.t_ns[0]) & (ds.truth.t_ns <= res.t_ns[-1]))
    dt_s = float(np.median(np.diff(ds.imu.t_ns))) / NS
    return {"navigated": len(res.t_ns), "of": n_imu, "lost_s": (n_imu - len(res.t_ns)) * dt_s,
            "final_m": float(_horizontal_error(ds, res, sel[-1:])[0]),
            "outage_m": m["outage_max_horizontal_max_m"]}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--duration", type=float, default=600.0, help="[s] of the simulated drive")
    p.add_argument("--kill-at", type=float, default=150.0, help="[s] into the drive")
    p.add_argument("--outage", default="300:60", help="GNSS outage START:DURATION [s]")
    p.add_argument("--cases", default=",".join(CASES), help=f"comma-separated, of {CASES}")
    p.add_argument("--out", type=Path, default=Path("out/fault_injection"))
    args = p.parse_args(argv)
    cases = [c for c in args.cases.split(",") if c]
    if not set(cases) <= set(CASES):
        p.error(f"--cases: choose from {CASES}")
    spec = DemoSpec("sim:car", {"duration_s": args.duration}, [parse_outage(args.outage)])
    settings = compensation_settings(spec.compensation, spec.seed)
    ds = load_dataset(spec.dataset, **spec.options)
    ds.config = nav_config(ds.config, load_filter_params(None))
    rows: dict[str, dict] = {}
    for case in cases:
        out = (args.out / case).resolve()
        out.mkdir(parents=True, exist_ok=True)
        for ckpt in (Path("out/checkpoint")).glob("*.ckpt"):
            ckpt.unlink()  # no checkpoint of an earlier run (a resumed ins takes only its own stream's anyway)
        log: dict = {}
        t0 = time.monotonic()
        print(f"--- {case}: {args.duration:g} s drive" + (f", SIGKILL at {args.kill_at:g} s" if case != "clean"
                                                           else "") + f" (log {out / 'launch.log'})", flush=True)
        try:
            _, got = run_set(DEMO_LAUNCH, out, spec, settings, limit_s=2.0 * args.duration + 600.0,
                             during=None if case == "clean" else killer(case, args.kill_at, log))
        except Exception as e:  # click.ClickException with the reason, or anything else: the row says it
            rows[case] = {"error": str(e) or type(e).__name__}
            traceback.print_exc()
            continue
        rows[case] = {"wall_s": time.monotonic() - t0, **log,
                      **{prefix: score(ds, *result_of(got, prefix)) for prefix in RUNS}}
        print(rows[case], flush=True)
    print_table(rows, cases)
    return 0


def print_table(rows: dict, cases: list) -> None:
    clean = rows.get("clean", {})
    print(f"\n{'case':<10} {'ins':<12} {'navigated':>16} {'lost s':>7} {'final m':>8} {'clean':>7} "
          f"{'outage m':>9} {'clean':>7} {'back s':>7} {'run s':>6}")
    for case in cases:
        r = rows[case]
        if "error" in r:
            print(f"{case:<10} FAILED: {r['error'][:200]}")
            continue
        for prefix, label in RUNS.items():
            s, c = r[prefix], clean.get(prefix, {})
            print(f"{case:<10} {label:<12} {s['navigated']:>8}/{s['of']:<7} {s['lost_s']:>7.2f} "
                  f"{s['final_m']:>8.2f} {c.get('final_m', float('nan')):>7.2f} {s['outage_m']:>9.2f} "
                  f"{c.get('outage_m', float('nan')):>7.2f} {r.get('back_s', float('nan')):>7.1f} "
                  f"{r['wall_s']:>6.0f}")


if __name__ == "__main__":
    sys.exit(main())
