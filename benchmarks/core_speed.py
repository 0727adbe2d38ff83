"""Speed of the navigation core (strapdown + 15-state ESKF + GNSS updates) in one process.

Prints, side by side and measured in the same run:
- epochs per second and real-time factor over a simulated 30 min car drive at 200 Hz with 1 Hz GNSS,
  median of --repeats runs, for covariance propagation every IMU sample and every --cov-interval seconds;
- the accuracy of both settings on the same drive (with a 60 s outage) and on the rtklibexplorer drive
  (with 30 s outages every 90 s), to show that the lower propagation rate leaves the accuracy unchanged.

    .venv/bin/python benchmarks/core_speed.py [--minutes 30] [--repeats 3] [--profile]
"""
from __future__ import annotations

import argparse
import cProfile
import pstats
import statistics

from zennav.datasets.errors import DataError
from zennav.datasets.registry import load_dataset
from zennav.metrics import evaluate
from zennav.replay import run_replay
from zennav.sim.scenarios import make_dataset


def run(ds, cov_interval_s: float, **replay_kw):
    ds.config = ds.config.with_(cov_interval_s=cov_interval_s)
    res = run_replay(ds, **replay_kw)
    return res, evaluate(ds, res)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--minutes", type=float, default=30.0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--cov-interval", type=float, default=0.05, help="lower covariance propagation interval [s]")
    ap.add_argument("--profile", action="store_true", help="print the top of a cProfile of one run")
    args = ap.parse_args()

    ds = make_dataset("car", duration_s=args.minutes * 60.0, imu_rate_hz=200.0, gnss_rate_hz=1.0, seed=0)
    settings = {"every sample": 0.0, f"every {args.cov_interval:g} s": args.cov_interval}
    mid_s = args.minutes * 30.0
    print(f"simulated car, {args.minutes:g} min, 200 Hz IMU, 1 Hz GNSS, 60 s outage at {mid_s:g} s; "
          f"{args.repeats} runs each")
    print(f"{'covariance propagation':<24}{'epochs/s (median)':>20}{'real-time (median)':>20}"
          f"{'horiz RMS m':>14}{'outage max m':>14}")
    for name, cov in settings.items():
        speeds, rtfs = [], []
        for _ in range(args.repeats):
            res, m = run(ds, cov, outages=[(mid_s, 60.0)])
            speeds.append(m["epochs_per_s"])
            rtfs.append(m["realtime_factor"])
        print(f"{name:<24}{statistics.median(speeds):>20,.0f}{statistics.median(rtfs):>19.1f}x"
              f"{m['horizontal_rms_m']:>14.3f}{m['outage_max_horizontal_max_m']:>14.3f}")

    try:
        real = load_dataset("rtklibexplorer")
    except DataError as e:
        print(f"rtklibexplorer drive not available ({e})")
    else:
        print("\nrtklibexplorer drive (100 Hz), 30 s outages every 90 s")
        print(f"{'covariance propagation':<24}{'horiz RMS m':>14}{'outage max-drift RMS m':>24}{'real-time':>12}")
        for name, cov in settings.items():
            res, m = run(real, cov, outage_every=(90.0, 30.0, 60.0))
            print(f"{name:<24}{m['horizontal_rms_m']:>14.3f}{m['outage_max_horizontal_rms_m']:>24.3f}"
                  f"{m['realtime_factor']:>11.1f}x")

    if args.profile:
        ds.config = ds.config.with_(cov_interval_s=args.cov_interval)
        prof = cProfile.Profile()
        prof.runcall(run_replay, ds)
        pstats.Stats(prof).sort_stats("tottime").print_stats(12)


if __name__ == "__main__":
    main()
