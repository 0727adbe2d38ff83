"""The 21-state option (IMU scale factors as states) against the 15-state filter on simulated drives with
scale-factor errors (exact truth), over seeds.

Per vehicle (car 900 s, multirotor 600 s, MEMS grade, scale-factor errors per axis simulated as the Gauss-Markov
process the filter is told: --ppm 1-sigma, the bias correlation time) and outage window length (GNSS withheld for
W s every W + 120 s after 180 s): the RMS of the per-window maximum horizontal error and the horizontal RMS of the
whole run (outages included) for 15 and 21 states, medians over seeds; and the consistency of the 21-state
filter's final scale-factor estimates against the simulated truth at the run's last sample, rms(error / sigma) over
axes and seeds, per sensor (1 means consistent): over all axes, and apart over the axes the run observed (final
sigma below OBSERVED_RATIO of the prior sigma) and those it left at their prior. An axis left at its prior (a car's
roll gyro scale: its roll rates are small) has error / sigma = -truth / sigma_prior whatever the filter does: it
samples the simulator's draw (expectation 1, but over 15 axes the rms of unit normals lies in [0.65, 1.35] only
95 % of the time; the draw's own rms on those axes is printed beside it); the observed axes tell whether the
filter's sigma of what it estimated is right.

    .venv/bin/python benchmarks/scale_factors.py [--seeds 0,1,2,3,4] [--ppm 3000] [--windows 30,60]
"""
from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from zennav.metrics import evaluate
from zennav.nav.navigator import Navigator
from zennav.replay import run_replay
from zennav.sim.scenarios import make_dataset

DURATION_S = {"car": 900.0, "multirotor": 600.0}
OBSERVED_RATIO = 0.5  # an axis counts as observed once its final sigma is below this fraction of its prior sigma


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", default="0,1,2,3,4")
    ap.add_argument("--ppm", type=float, default=3000.0, help="1-sigma of the scale-factor errors [ppm]")
    ap.add_argument("--windows", default="30,60", help="outage window lengths [s]")
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    windows = [float(w) for w in args.windows.split(",")]
    print(f"scale-factor errors 1-sigma {args.ppm:.0f} ppm per axis; seeds {seeds}; medians over seeds")
    print(f"{'vehicle':>11}{'window s':>9}{'15: outage m':>14}{'21: outage m':>14}{'change':>8}"
          f"{'15: run m':>12}{'21: run m':>12}")
    for kind, duration in DURATION_S.items():
        # per sensor: (error / sigma, final sigma / prior sigma, truth / prior sigma) of each axis and seed
        z: dict[str, list[tuple[float, float, float]]] = {"gyro_scale": [], "accel_scale": []}
        for w in windows:
            rows = []
            for seed in seeds:
                ds = make_dataset(kind, duration_s=duration, seed=seed, scale_ppm=(args.ppm, args.ppm))
                row = []
                for states in (15, 21):
                    d = replace(ds, config=ds.config.with_(scale_factors=states == 21))
                    nav = Navigator(d.config, d.initial)
                    m = evaluate(d, run_replay(d, outage_every=(180.0, w, 120.0), navigator=nav))
                    row += [m["outage_max_horizontal_rms_m"], m["horizontal_rms_m"]]
                    if states == 21 and w == windows[0]:
                        k = int(np.searchsorted(ds.imu.t_ns, nav.t_ns))  # the truth at the filter's last sample
                        for name in z:
                            sl, truth = nav.aug_blocks[name], ds.notes[name][k]
                            sigma, prior = np.sqrt(np.diag(nav.P)[sl]), getattr(d.config.imu_noise, f"{name}_std")
                            z[name] += zip((nav.aug_value(sl) - truth) / sigma, sigma / prior, truth / prior)
                rows.append(row)
            o15, f15, o21, f21 = np.median(np.array(rows), axis=0)
            print(f"{kind:>11}{w:>9.0f}{o15:>14.2f}{o21:>14.2f}{(o21 / o15 - 1) * 100:>7.0f}%{f15:>12.3f}{f21:>12.3f}",
                  flush=True)
        for name, label in (("gyro_scale", "gyro"), ("accel_scale", "accelerometer")):
            e, ratio, draw = np.array(z[name]).T
            seen = ratio < OBSERVED_RATIO
            print(f"{kind:>11}  21-state {label} scale rms(error/sigma): all {_rms(e)} ({len(e)} axes); observed "
                  f"{_rms(e[seen])} ({seen.sum()} axes, final/prior sigma {_span(ratio[seen])}); at prior "
                  f"{_rms(e[~seen])} ({(~seen).sum()} axes, final/prior sigma {_span(ratio[~seen])}; "
                  f"rms(truth/prior sigma) {_rms(draw[~seen])})", flush=True)


def _rms(x: np.ndarray) -> str:
    return f"{np.sqrt(np.mean(np.square(x))):.2f}" if len(x) else "-"


def _span(x: np.ndarray) -> str:
    return f"{x.min():.2f}..{x.max():.2f}" if len(x) else "-"


if __name__ == "__main__":
    main()
