"""The 21-state option (IMU scale factors as states) against the 15-state filter on simulated drives with
scale-factor errors (exact truth), over seeds.

Per vehicle (car 900 s, multirotor 600 s, MEMS grade, scale-factor errors per axis simulated as the Gauss-Markov
process the filter is told: --ppm 1-sigma, the bias correlation time) and outage window length (GNSS withheld for
W s every W + 120 s after 180 s): the RMS of the per-window maximum horizontal error and the horizontal RMS of the
whole run (outages included) for 15 and 21 states, medians over seeds; and the consistency of the 21-state
filter's scale-factor estimates against the simulated truth, rms(error / sigma) per sensor (1 means consistent),
over axes and seeds at the run's end, and over axes, seeds and samples every EVERY_S of the run (the first window
length's runs): over all axes, and apart over the axes the run had observed (sigma below OBSERVED_RATIO of the prior
sigma) and those still at their prior. An axis at its prior (a car's roll gyro scale: its roll rates are small) has
error / sigma = -truth / sigma_prior whatever the filter does: it samples the simulator's draw (the draw's own rms
is printed beside it); the observed axes tell whether the filter's sigma of what it estimated is right. The end's
statistic is one sample per axis and seed (over 9 axes the rms of unit normals lies in [0.55, 1.45] only 95 % of the
time, over 3 in [0.27, 1.77]); the samples every EVERY_S are correlated in time but average what one epoch draws.

    .venv/bin/python benchmarks/scale_factors.py [--seeds 0,1,2,3,4] [--ppm 3000] [--windows 30,60]
"""
from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from zennav.metrics import ScaleFactorErrors, evaluate
from zennav.nav.navigator import Navigator
from zennav.replay import run_replay
from zennav.sim.scenarios import make_dataset

DURATION_S = {"car": 900.0, "multirotor": 600.0}
OBSERVED_RATIO = 0.5  # an axis counts as observed once its sigma is below this fraction of its prior sigma
EVERY_S = 30.0  # consistency samples every EVERY_S of a run [s] (DURATION_S are multiples: the last is the end)


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
        # (error / sigma, sigma / prior sigma, truth / prior sigma), (K, 6) per seed, every EVERY_S of the run
        recs = []
        for w in windows:
            rows = []
            for seed in seeds:
                ds = make_dataset(kind, duration_s=duration, seed=seed, scale_ppm=(args.ppm, args.ppm))
                row = []
                for states in (15, 21):
                    d = replace(ds, config=ds.config.with_(scale_factors=states == 21))
                    rec = ScaleFactorErrors(d, EVERY_S) if states == 21 and w == windows[0] else None
                    res = run_replay(d, outage_every=(180.0, w, 120.0), navigator=Navigator(d.config, d.initial),
                                     on_epoch=rec)
                    m = evaluate(d, res)
                    row += [m["outage_max_horizontal_rms_m"], m["horizontal_rms_m"]]
                    if rec is not None:
                        recs.append(np.array([rec.z, rec.ratio, rec.draw]))
                rows.append(row)
            o15, f15, o21, f21 = np.median(np.array(rows), axis=0)
            print(f"{kind:>11}{w:>9.0f}{o15:>14.2f}{o21:>14.2f}{(o21 / o15 - 1) * 100:>7.0f}%{f15:>12.3f}{f21:>12.3f}",
                  flush=True)
        for axes, label in ((slice(0, 3), "gyro"), (slice(3, 6), "accelerometer")):
            final = np.concatenate([r[:, -1, axes] for r in recs], axis=1)  # the last sample: the run's end
            every = np.concatenate([r[:, :, axes].reshape(3, -1) for r in recs], axis=1)
            print(f"{kind:>11}  21-state {label} scale rms(error/sigma): at the end {_split(final, 'axes')}; "
                  f"every {EVERY_S:.0f} s {_split(every, 'samples')}", flush=True)


def _split(x: np.ndarray, unit: str) -> str:
    """All, observed and at-prior rms of error / sigma, from rows (error / sigma, sigma ratio, truth / prior)."""
    e, ratio, draw = x
    seen = ratio < OBSERVED_RATIO
    return (f"all {_rms(e)} ({len(e)} {unit}); observed {_rms(e[seen])} ({seen.sum()}, sigma/prior "
            f"{_span(ratio[seen])}); at prior {_rms(e[~seen])} ({(~seen).sum()}, sigma/prior {_span(ratio[~seen])}, "
            f"rms(truth/prior sigma) {_rms(draw[~seen])})")


def _rms(x: np.ndarray) -> str:
    return f"{np.sqrt(np.mean(np.square(x))):.2f}" if len(x) else "-"


def _span(x: np.ndarray) -> str:
    return f"{x.min():.2f}..{x.max():.2f}" if len(x) else "-"


if __name__ == "__main__":
    main()
