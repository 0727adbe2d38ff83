"""Outage benchmark of the vehicle constraints (issue 18): non-holonomic constraint, zero velocity/angular rate at
standstills, the odometer, and the learned compensation stacked on them.

rtklibexplorer (real car, MEMS IMU, RTK reference): GNSS withheld for L = 10, 30, 60 s every 90 s, the first at
120 s; per row the RMS and the maximum over the windows of the per-window maximum horizontal drift, and the change
of that RMS against pure INS, and the RMS of the along-track and cross-track parts of each window's peak error
(against the true course: the forward-speed and heading parts of the drift). Rows: pure INS; NHC; NHC+ZUPT;
NHC+ZUPT with learned compensation (anfis, elman; each for --seeds, and their median; with --forward-only the
learned body velocity gives the forward speed alone, NavConfig.learn_forward_only; --where-better off|nhc|on: an
output is fused only where its 1-sigma is below the filter's, never, under the NHC, always,
NavConfig.learn_where_better; --held-fraction F: that part of
each answer's variance is a bias held through the outage, NavConfig.learn_held_fraction; --nhc-floor: the lateral
and vertical 1-sigma at least the constraint's, NavConfig.learn_nhc_floor; --consistency: each output's R from its
innovations against the filter, NavConfig.learn_consistency). Under each learned run, its
answers against the truth: the RMS error of the answered body velocity (forward, right, down) [m/s] against the
true velocity in the solution's body frame at the query time, and the mean of (error / answered 1-sigma)^2 per
output (about 1 for an honest 1-sigma, above 1: the filter weighs the answer too much). --per-window: each row's
per-window maxima, in time order (a few windows: one bad window can set the RMS). Each row is one product run,
the same as
    zennav replay rtklibexplorer --outage-every 90:L:120 --constraints nhc,zupt [--compensation anfis --seed S]
sim:car (600 s, MEMS, its odometer 2 % fast with 0.05 m/s noise): the same windows, NHC+ZUPT without and with the
odometer (scale-factor state estimated), and the scale factor's final estimate.

    .venv/bin/python benchmarks/constraints.py [--windows 10,30,60] [--seeds 0,1,2] [--jobs 2] [--no-learned]
        [--datasets rtklibexplorer,sim:car] [--forward-only] [--where-better off|nhc|on] [--held-fraction F]
        [--nhc-floor]
        [--consistency] [--per-window] [--models anfis,elman]
"""
from __future__ import annotations

import argparse
import math
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

PERIOD_S, FIRST_S = 90.0, 120.0
ROWS = [("INS", ()), ("NHC", ("nhc",)), ("NHC+ZUPT", ("nhc", "zupt"))]
SIM_ROWS = [("INS", ()), ("NHC+ZUPT", ("nhc", "zupt")), ("NHC+ZUPT+ODO", ("nhc", "zupt", "odo"))]
LEARNED = ("anfis", "elman")


def run(job: tuple) -> tuple:
    """One product run: (spec, window length, constraint names, compensation, seed, learned options
    ((NavConfig field name, value) pairs)) -> (job,
    per-window maxima, along/cross parts, odometer scale (estimate, 1-sigma, truth) or None, the learned answers'
    accuracy (answer_errors) or None, wall s)."""
    import torch

    from zennav.datasets.registry import load_dataset
    from zennav.learn.loop import make_compensator
    from zennav.metrics import evaluate
    from zennav.nav.navigator import Navigator
    from zennav.params import nav_config
    from zennav.replay import run_replay
    from zennav.replay_cli import filter_settings

    torch.set_num_threads(1)
    spec, length, constraints, compensation, seed, options = job
    wall = time.perf_counter()
    ds = load_dataset(spec)
    ds.config = nav_config(ds.config, filter_settings(spec, None, None, list(constraints))).with_(
        **dict(options))
    compensator = make_compensator(compensation, "body_velocity", seed)
    config = ds.config.with_(learning=True) if compensator is not None else ds.config
    logged = None if compensator is None else AnswerLog(compensator)
    nav = Navigator(config, ds.initial)
    res = run_replay(ds, outage_every=(PERIOD_S, length, FIRST_S), navigator=nav, compensator=logged)
    drifts = [o["max_horizontal_m"] for o in evaluate(ds, res)["outages"]]
    parts = along_cross(ds, res)
    scale = None
    if "odo_scale" in nav.aug_blocks:
        sl = nav.aug_blocks["odo_scale"]
        scale = (float(nav.aug_value(sl)[0]), math.sqrt(nav.P[sl, sl][0, 0]), ds.notes.get("odo_scale_error"))
    return (job, drifts, parts, scale, answer_errors(ds, res, [] if logged is None else logged.answers),
            time.perf_counter() - wall)


class AnswerLog:
    """An in-process learning loop (zennav.learn.loop.InProcessLoop) that keeps its answers: answers [(query t_ns,
    value, 1-sigma)]."""

    def __init__(self, loop):
        self.loop, self.target, self.answers = loop, loop.target, []

    @property
    def last_refusal(self) -> str:
        return self.loop.last_refusal

    def add(self, samples) -> None:
        self.loop.add(samples)

    def predict(self, query):
        out = self.loop.predict(query)
        if out is not None:
            self.answers.append((query.t_ns, *out))
        return out


def answer_errors(ds, res, answers) -> tuple[int, np.ndarray, np.ndarray] | None:
    """Body-velocity answers [(t_ns, value (3,) [m/s, FRD], 1-sigma (3,))] against the true velocity rotated into
    the solution's body frame at the query time: (count, RMS error per output [m/s], mean (error / 1-sigma)^2 per
    output). None without answers or true velocity."""
    from zennav.nav.rotation import quat_to_dcm

    truth = ds.truth
    if not answers or truth is None or truth.v_n is None:
        return None
    t_ref = truth.t_ns.astype(float)
    err, z2 = [], []
    for t_ns, value, std in answers:
        i = min(int(np.searchsorted(res.t_ns, t_ns)), len(res.t_ns) - 1)
        v_n = np.array([np.interp(float(t_ns), t_ref, truth.v_n[:, k]) for k in range(3)])
        e = np.asarray(value) - quat_to_dcm(res.q_nb[i]).T @ v_n
        err.append(e)
        z2.append((e / np.asarray(std)) ** 2)
    return len(err), np.sqrt(np.mean(np.square(err), axis=0)), np.mean(z2, axis=0)


def along_cross(ds, res) -> np.ndarray | None:
    """Per withheld window, the along-track and cross-track components [m] of the horizontal error at its peak
    (the error of evaluate's per-window maximum), along the true course at the peak (the last true velocity
    faster than 1 m/s up to it): the forward-speed and heading parts of the drift. None without true velocity."""
    from zennav.metrics import antenna_llh, ned_errors

    truth = ds.truth
    if truth is None or truth.v_n is None:
        return None
    sel = (truth.t_ns >= res.t_ns[0]) & (truth.t_ns <= res.t_ns[-1])
    t_ref, v_ref = truth.t_ns[sel], truth.v_n[sel]
    llh = antenna_llh(res.llh, res.q_nb, ds.config.lever_arm_b) if truth.at_antenna else res.llh
    est = np.stack([np.interp((t_ref - res.t_ns[0]).astype(float), (res.t_ns - res.t_ns[0]).astype(float), llh[:, i])
                    for i in range(3)], -1)
    err = ned_errors(est, truth.llh[sel])[:, :2]
    moving = np.flatnonzero(np.hypot(v_ref[:, 0], v_ref[:, 1]) > 1.0)
    out = []
    for a, b in res.windows:
        inside = np.flatnonzero((t_ref >= a) & (t_ref < b))
        if len(inside) == 0:
            continue
        k = inside[np.argmax(np.hypot(err[inside, 0], err[inside, 1]))]
        j = moving[max(int(np.searchsorted(moving, k, side="right")) - 1, 0)]
        u = v_ref[j, :2] / np.hypot(v_ref[j, 0], v_ref[j, 1])
        out.append((err[k] @ u, err[k] @ np.array([-u[1], u[0]])))
    return np.array(out)


def _stats(drifts) -> tuple[float, float]:
    d = np.asarray(drifts, dtype=float)
    return float(np.sqrt(np.mean(d**2))), float(d.max())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--windows", default="10,30,60")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--no-learned", action="store_true", help="skip the learned rows (minutes each)")
    ap.add_argument("--datasets", default="rtklibexplorer,sim:car")
    ap.add_argument("--forward-only", action="store_true",
                    help="learned rows fuse the forward body velocity alone (learn_forward_only)")
    ap.add_argument("--where-better", choices=("off", "nhc", "on"), default="",
                    help="learned rows fuse an output only where its 1-sigma is below the filter's: on, nhc (while"
                         " the NHC is on), off (learn_where_better; default: the parameter file's)")
    ap.add_argument("--held-fraction", type=float, default=0.0,
                    help="learned rows: this part of each answer's variance is a bias held through the outage"
                         " (learn_held_fraction)")
    ap.add_argument("--nhc-floor", action="store_true",
                    help="learned rows: lateral and vertical 1-sigma at least the constraint's (learn_nhc_floor)")
    ap.add_argument("--consistency", action="store_true",
                    help="learned rows: each output's R from its innovations against the filter (learn_consistency)")
    ap.add_argument("--per-window", action="store_true", help="print each row's per-window maxima")
    ap.add_argument("--models", default=",".join(LEARNED), help="learned rows of these models (anfis, elman)")
    args = ap.parse_args()
    lengths = [float(x) for x in args.windows.split(",")]
    seeds = [int(x) for x in args.seeds.split(",")]
    specs = args.datasets.split(",")
    models = [m for m in LEARNED if m in args.models.split(",")]
    options = tuple((name, value) for name, value in (
        ("learn_forward_only", args.forward_only), ("learn_where_better", args.where_better),
        ("learn_held_fraction", args.held_fraction), ("learn_nhc_floor", args.nhc_floor),
        ("learn_consistency", args.consistency)) if value)
    jobs: list[tuple] = []
    for length in lengths:
        if "rtklibexplorer" in specs:
            jobs += [("rtklibexplorer", length, cons, "none", 0, ()) for _, cons in ROWS]
            if not args.no_learned:
                jobs += [("rtklibexplorer", length, ("nhc", "zupt"), model, s, options)
                         for model in models for s in seeds]
        if "sim:car" in specs:
            jobs += [("sim:car", length, cons, "none", 0, ()) for _, cons in SIM_ROWS]
    wall = time.perf_counter()
    with ProcessPoolExecutor(args.jobs) as pool:
        results = {job: rest for job, *rest in pool.map(run, jobs)}
    print(f"GNSS withheld for L s every {PERIOD_S:g} s from {FIRST_S:g} s; per-window maximum horizontal drift [m]; "
          "along / cross: RMS of the along- and cross-track parts of each window's peak error [m]\neach row is the "
          f"product run  zennav replay DATASET --outage-every {PERIOD_S:g}:L:{FIRST_S:g} --constraints LIST "
          "[--compensation MODEL --seed S]" + "".join(f" with {o}: {str(v).lower()} in --params FILE"
                                                    for o, v in options))
    for spec, rows in (("rtklibexplorer", ROWS), ("sim:car", SIM_ROWS)):
        if spec not in specs:
            continue
        print(f"\n{spec}\n{'window':>7}{'constraints':>14}{'learned':>14}{'windows':>9}{'RMS m':>9}{'max m':>9}"
              f"{'vs INS':>9}{'along m':>9}{'cross m':>9}")
        for length in lengths:
            base = _stats(results[(spec, length, (), "none", 0, ())][0])[0]

            def line(label, learned, n, rms, mx, parts=None, base=base, length=length, drifts=None):
                split = "" if parts is None else "".join(f"{np.sqrt(np.mean(p**2)):>9.2f}" for p in parts.T)
                print(f"{length:>6.0f}s{label:>14}{learned:>14}{n:>9}{rms:>9.2f}{mx:>9.2f}"
                      f"{100.0 * (rms - base) / base:>8.0f}%{split}")
                if args.per_window and drifts is not None:
                    print(f"{'':>21}per window: {' '.join(f'{d:.2f}' for d in drifts)}")

            for label, cons in rows:
                drifts, parts, scale, _, _ = results[(spec, length, cons, "none", 0, ())]
                line(label, "", len(drifts), *_stats(drifts), parts, drifts=drifts)
                if scale is not None:
                    print(f"{'':>21}odometer scale error {100 * scale[0]:.3f} % +- {100 * scale[1]:.3f} % "
                          f"(simulated {100 * scale[2]:.3f} %)")
            if spec == "rtklibexplorer" and not args.no_learned:
                for model in models:
                    learned = [results[(spec, length, ("nhc", "zupt"), model, s, options)] for s in seeds]
                    runs = [r[0] for r in learned]
                    for s, (drifts, parts, _, acc, _) in zip(seeds, learned):
                        line("NHC+ZUPT", f"{model} s{s}", len(drifts), *_stats(drifts), parts, drifts=drifts)
                        if acc is not None:
                            print(f"{'':>21}{acc[0]} answers: error RMS {np.array2string(acc[1], precision=2)} "
                                  f"m/s, (error/sigma)^2 {np.array2string(acc[2], precision=2)} (fwd, right, down)")
                    stats = np.array([_stats(d) for d in runs])
                    line("NHC+ZUPT", f"{model} median", len(runs[0]), *np.median(stats, axis=0).tolist())
    print(f"\n{len(jobs)} runs in {time.perf_counter() - wall:.0f} s with {args.jobs} processes")


if __name__ == "__main__":
    main()
