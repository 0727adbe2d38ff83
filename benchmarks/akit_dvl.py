"""DVL fusion on the A-KIT AUV trajectories (zennav replay akit:TrajectoryN): loose EKF, tight EKF, tight VBKF, ...
one row per trajectory x method, against the reference (a post-processed Phins solution, not independent of the
IMU/DVL: see zennav.datasets.akit).

Each run is the product's replay (zennav.replay.run_replay, the engine's own DVL and depth sources) of the loader's
dataset: the IMU shifted by the estimated skew, the derived DVL beams (and velocity for the loose filter), the
derived depth, and derived GNSS fixes during the first --gnss-s seconds only ("at the surface"; 0: none, the whole
run under water from the reference's initial state). Figures per row:
- RMSE: horizontal position RMS over the whole run [m] (zennav.metrics.evaluate at the reference rows);
- final: horizontal error at the last reference row [m];
- drift: final / horizontal distance travelled since the last GNSS fix (the start when none) [%].
A first table describes the data of each trajectory: the estimated IMU/reference skew [s], the distance travelled
[m], the yaw travel (sum of |heading change| between reference rows, waves included) [rad], the gyro-only
attitude RMS error [deg] against the reference (large: the IMU and the reference disagree beyond what the filter
can fix: bad data, not a bad filter), and the drift of the DVL's own dead reckoning with the reference attitude
from the last GNSS fix [%] (dvl_dead_reckoning: the floor of a filter that fuses this DVL as it is).

METHODS is the one list of what is compared: name -> run(dataset) -> ReplayResult. Another method (e.g. a learned
compensation) is one more entry.

The learned method, "tight VBKF + PSO-ANFIS" (seed 003: tight VBKF whose DVL source learns its beam errors and
compensates the beams its anomaly discrimination judges anomalous, zennav.nav.aid.dvl_learned), needs a model
trained on OTHER trajectories (--train, default 1-11; the data's authors train on 11 segments and test on 2, and
T12/T13 are the cleanest): each training trajectory is replayed by the same product loop (zennav.learn.loop,
anfis-ipso, target dvl_beam) with derived GNSS over the WHOLE run (--train-gnss-s: the vehicle "at the surface",
the GNSS-aided filter the reference of the beam errors, as the seed's PHINS + GPS) and with the seed's anomaly
kinds injected from the start (--train-anomalies, seeded), so that the training samples contain anomalous
measurements (seed step 2). The last set is written to --model-out and every test run loads it (InProcessLoop
.load_model: frozen, nothing learned from the test trajectory). With --seeds 0,1,2 each seed retrains (the
injection and the model seed; --model with "{seed}" loads one model per seed instead), --also-clean runs the clean DVL
through the same models too, and a last table gives per condition and method the mean RMSE over the trajectories of
each seed, the median over the seeds and that median against the tight EKF's (the issue's "X % lower RMSE").

    .venv/bin/python benchmarks/akit_dvl.py [--trajectories 1-13] [--methods "loose EKF,tight EKF"] [--gnss-s 60]
        [--anomalies all --anomalies-from-s 60 [--also-clean]] [--seeds 0]
    .venv/bin/python benchmarks/akit_dvl.py --trajectories 12,13 --train 1-11 --anomalies all --also-clean \
        --seeds 0,1,2,3,4,5,6,7,8,9 --methods "loose EKF,tight EKF,tight VBKF,tight VBKF + PSO-ANFIS"
"""
from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from zennav.datasets.akit import gyro_attitude
from zennav.datasets.registry import akit_specs, load_dataset
from zennav.learn.loop import InProcessLoop, make_compensator
from zennav.learn.settings import compensation_settings
from zennav.metrics import drift, evaluate, ned_errors
from zennav.nav import earth
from zennav.nav.rotation import euler_to_dcm, wrap_angle
from zennav.nav.types import NS, Dataset
from zennav.replay import ReplayResult, run_replay


def _with_config(**settings) -> Callable[[Dataset], ReplayResult]:
    """A method that replays the dataset with these NavConfig settings."""
    return lambda ds: run_replay(replace(ds, config=ds.config.with_(**settings)))


METHODS: dict[str, Callable[[Dataset], ReplayResult]] = {
    "loose EKF": _with_config(dvl_mode="loose", vb_dvl=False),
    "tight EKF": _with_config(dvl_mode="tight", vb_dvl=False),
    "tight VBKF": _with_config(dvl_mode="tight", vb_dvl=True),
}
LEARNED = "tight VBKF + PSO-ANFIS"  # needs a trained model (train_dvl_model); added to METHODS by main
LEARNED_COMPENSATION = "anfis-ipso"  # seed 003's improved PSO (zennav.learn.pso.IMPROVED)
LEARNED_CONFIG = {"dvl_mode": "tight", "vb_dvl": True}
TRAIN_WINDOW = 50_000  # samples: every training sample of 11 dives (4 beams x 1 Hz x 400 s each at most)


def train_dvl_model(trajectories: list[int], options: dict, seed: int, path) -> dict:
    """Replay the training trajectories through one learning loop (module docstring) and write its last set to
    path; returns the loop's status counters."""
    # all the training samples in one fit at the end (the default window keeps the newest 2000: two dives)
    loop = InProcessLoop("dvl_beam", compensation_settings(LEARNED_COMPENSATION, seed).with_(
        window=TRAIN_WINDOW, retrain_samples=TRAIN_WINDOW))
    for n in trajectories:
        ds = load_dataset(f"akit:Trajectory{n}", **options)
        run_replay(replace(ds, config=ds.config.with_(**LEARNED_CONFIG)), compensator=loop)
    loop.save_model(path)
    return loop.status()


def learned_method(path) -> Callable[[Dataset], ReplayResult]:
    """The learned method with the model in path, loaded afresh (frozen) for every run."""
    def run(ds: Dataset) -> ReplayResult:
        loop = make_compensator(LEARNED_COMPENSATION, "dvl_beam")
        assert loop is not None
        loop.load_model(path)
        return run_replay(replace(ds, config=ds.config.with_(**LEARNED_CONFIG)), compensator=loop)
    return run


def score(ds: Dataset, res: ReplayResult) -> dict:
    """RMSE [m], final horizontal error [m], distance since the last GNSS fix [m] and drift [%] of a run."""
    m = evaluate(ds, res)
    truth = ds.truth
    assert truth is not None
    end = int(np.searchsorted(truth.t_ns, res.t_ns[-1], side="right")) - 1
    est = np.array([np.interp(truth.t_ns[end], res.t_ns, res.llh[:, i]) for i in range(3)])
    final = float(np.hypot(*ned_errors(est[None], truth.llh[end][None])[0, :2]))
    rows = (truth.t_ns >= _last_fix_ns(ds, int(res.t_ns[0]))) & (truth.t_ns <= truth.t_ns[end])
    distance, pct = drift(truth.llh[rows], final)
    return {"rmse_m": m["horizontal_rms_m"], "final_m": final, "distance_m": distance,
            "drift_pct": math.nan if pct is None else pct, "engine": m["engine"]}


def _last_fix_ns(ds: Dataset, start_ns: int) -> int:
    """Where a run's drift is counted from: the last GNSS fix, start_ns when there is none [ns]."""
    return int(ds.gnss.t_ns[-1]) if len(ds.gnss) else start_ns


def dvl_dead_reckoning(ds: Dataset, yaw_rad: float = 0.0, scale: float = 0.0) -> float:
    """Drift [%] of the DVL's own dead reckoning, the floor of a filter that trusts this DVL: its velocity (v_d, the
    DVL frame = body frame at the IMU, zennav.datasets.akit) rotated by the REFERENCE attitude and integrated
    (trapezoid) from the reference position at the last GNSS fix; an invalid velocity holds the last valid one.
    Same definition of drift as score. A calibration (yaw_rad, scale: v_d = (1 + scale) R_z(yaw_rad) v_b, as
    benchmarks/akit_dvl_floor.py fits it) is taken out first: v_b = R_z(-yaw_rad) v_d / (1 + scale)."""
    truth, dvl = ds.truth, ds.dvl
    assert truth is not None and truth.euler is not None and dvl is not None and dvl.velocity_d is not None
    t0 = _last_fix_ns(ds, int(truth.t_ns[0]))
    k = (dvl.t_ns >= max(t0, int(truth.t_ns[0]))) & (dvl.t_ns <= truth.t_ns[-1])
    t_ns, v_d = dvl.t_ns[k], dvl.velocity_d[k].copy()
    ok = np.ones(len(t_ns), dtype=bool) if dvl.velocity_valid is None else dvl.velocity_valid[k].astype(bool)
    ok &= np.all(np.isfinite(v_d), axis=1)
    v_d = v_d[np.maximum.accumulate(np.where(ok, np.arange(len(ok)), 0))]  # hold the last valid velocity
    v_d = v_d @ euler_to_dcm(np.array([0.0, 0.0, -yaw_rad])).T / (1.0 + scale)
    euler = np.column_stack([np.interp(t_ns, truth.t_ns, np.unwrap(truth.euler[:, i])) for i in range(3)])
    v_n = np.array([euler_to_dcm(e) @ v for e, v in zip(euler, v_d, strict=True)])
    ned_ref = earth.llh_to_ned(truth.llh, truth.llh[0])
    p0 = np.array([np.interp(t_ns[0], truth.t_ns, ned_ref[:, i]) for i in range(3)])
    p = p0 + np.vstack([np.zeros(3), np.cumsum(0.5 * (v_n[1:] + v_n[:-1]) * np.diff(t_ns)[:, None] / NS, axis=0)])
    end = int(np.searchsorted(truth.t_ns, t_ns[-1], side="right")) - 1
    p_end = np.array([np.interp(truth.t_ns[end], t_ns, p[:, i]) for i in range(3)])
    rows = (truth.t_ns >= t0) & (truth.t_ns <= truth.t_ns[end])
    _, pct = drift(truth.llh[rows], float(np.hypot(*(p_end - ned_ref[end])[:2])))
    return math.nan if pct is None else pct


def data_quality(ds: Dataset) -> dict:
    """Skew [s], distance [m], yaw travel [rad], gyro-only attitude RMS [deg] and the DVL dead-reckoning drift [%]
    of a trajectory."""
    truth = ds.truth
    assert truth is not None and truth.euler is not None
    t, euler = gyro_attitude(ds.imu, ds.initial.t_ns, ds.initial.euler, float(ds.initial.llh[0]))
    rows = (truth.t_ns > t[0]) & (truth.t_ns <= t[-1])
    k = np.searchsorted(t, truth.t_ns[rows])
    rms = np.degrees(np.sqrt(np.mean(wrap_angle(euler[k] - truth.euler[rows]) ** 2, axis=0)))
    return {"skew_s": ds.notes["skew_s"], "distance_m": drift(truth.llh, 0.0)[0],
            "turn_rad": float(np.sum(np.abs(np.diff(np.unwrap(truth.euler[:, 2]))))), "gyro_rms_deg": rms,
            "dvl_dr_pct": dvl_dead_reckoning(ds)}


def parse_trajectories(text: str) -> list[int]:
    """Trajectory numbers of "1-11", "2,12,13" or "1-3,12"."""
    out: list[int] = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        out += list(range(int(a), int(b or a) + 1))
    return out


def run_condition(trajectories: list[int], methods: list[str], options: dict, title: str) -> dict[str, list[dict]]:
    """The data table and one row per trajectory x method (module docstring) for these loader options; returns
    method -> the score of each trajectory."""
    print(f"\n{title}")
    print(f"{'trajectory':<13}{'skew s':>8}{'dist m':>8}{'yaw travel rad':>15}{'gyro-only r/p/y RMS deg':>26}"
          f"{'DVL DR drift %':>16}")
    datasets = {}
    for n in trajectories:
        ds = datasets[n] = load_dataset(f"akit:Trajectory{n}", **options)
        q = data_quality(ds)
        print(f"Trajectory{n:<3}{q['skew_s']:>+8.3f}{q['distance_m']:>8.0f}{q['turn_rad']:>15.2f}"
              f"{'/'.join(f'{x:.2f}' for x in q['gyro_rms_deg']):>26}{q['dvl_dr_pct']:>16.3f}", flush=True)
    print(f"\n{'trajectory':<13}{'method':<22}{'RMSE m':>9}{'final m':>9}{'drift %':>9}{'DVL fused':>10}")
    results: dict[str, list[dict]] = {m: [] for m in methods}
    for n, ds in datasets.items():
        for name in methods:
            s = score(ds, METHODS[name](ds))
            results[name].append(s)
            counters = s["engine"]["counters"]
            fused = counters.get("dvl_fused", 0) + counters.get("dvl_loose_fused", 0)
            decisions = ", ".join(f"{k[12:]} {v}" for k, v in sorted(counters.items()) if k.startswith("dvl_learned_"))
            print(f"Trajectory{n:<3}{name:<22}{s['rmse_m']:>9.2f}{s['final_m']:>9.2f}{s['drift_pct']:>9.3f}"
                  f"{fused:>10}" + (f"   beams: {decisions}" if decisions else ""), flush=True)
    print(f"\n{'all':<13}{'method':<22}{'RMSE m':>9}{'final m':>9}{'drift %':>9}   (means over the trajectories)")
    for name, rows in results.items():
        print(f"{'mean':<13}{name:<22}{np.mean([r['rmse_m'] for r in rows]):>9.2f}"
              f"{np.mean([r['final_m'] for r in rows]):>9.2f}{np.mean([r['drift_pct'] for r in rows]):>9.3f}"
              f"   median drift {np.median([r['drift_pct'] for r in rows]):.3f} %")
    return results


def print_summary(table: dict[tuple[str, str], dict[int, list[dict]]], seeds: list[int]) -> None:
    """Per condition and method: the RMSE mean over the trajectories of each seed, their median over the seeds and
    that median against the tight EKF's of the same condition; and the median of the per-seed changes against the
    tight EKF of the same seed (the anomalies' times move with the seed: a bias jump late in a dive costs little)."""
    print(f"\nsummary: RMSE [m], mean over the trajectories per seed; median over seeds {seeds}")
    print(f"{'condition':<11}{'method':<24}" + "".join(f"{f's{k}':>8}" for k in seeds)
          + f"{'median':>8}{'vs tight EKF':>14}{'per seed':>10}")
    for (condition, name), per_seed in table.items():
        means = np.array([float(np.mean([r["rmse_m"] for r in per_seed[k]])) for k in seeds])
        ekf = table.get((condition, "tight EKF"))
        rel = ""
        if ekf is not None:
            ref = np.array([np.mean([r["rmse_m"] for r in ekf[k]]) for k in seeds])
            rel = (f"{100.0 * (np.median(means) / np.median(ref) - 1.0):>+13.1f}%"
                   f"{100.0 * np.median(means / ref - 1.0):>+9.1f}%")
        print(f"{condition:<11}{name:<24}" + "".join(f"{m:>8.2f}" for m in means) + f"{np.median(means):>8.2f}{rel}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trajectories", default=f"1-{len(akit_specs())}", help="e.g. 1-13 or 2,12,13")
    ap.add_argument("--methods", default=",".join(METHODS), help=f"comma-separated of: {', '.join(METHODS)}")
    ap.add_argument("--gnss-s", type=float, default=60.0, help="derived GNSS fixes during the first S seconds")
    ap.add_argument("--anomalies", default=None, help="DVL anomaly spec (zennav.datasets.dvl_anomalies)")
    ap.add_argument("--anomalies-from-s", type=float, default=None, help="[s from the start; default --gnss-s]")
    ap.add_argument("--also-clean", action="store_true", help="with --anomalies: the clean DVL too, same models")
    ap.add_argument("--seeds", "--seed", default="0", help="e.g. 0 or 0,1,2: derived noise, anomalies, model")
    ap.add_argument("--train", default="1-11", help=f"{LEARNED}: the training trajectories")
    ap.add_argument("--train-gnss-s", type=float, default=400.0, help=f"{LEARNED}: derived GNSS in training [s]")
    ap.add_argument("--train-anomalies", default="all", help=f"{LEARNED}: anomalies injected in training")
    ap.add_argument("--model", default=None, help=f"{LEARNED}: use this trained model (no training; {{seed}} is "
                    "replaced by the seed)")
    ap.add_argument("--model-out", default="out/akit_dvl_beam_model_s{seed}.msgpack", help=f"{LEARNED}: where "
                    "training writes the model ({seed} is replaced by the seed)")
    args = ap.parse_args()
    methods = [m.strip() for m in args.methods.split(",")]
    unknown = [m for m in methods if m not in [*METHODS, LEARNED]]
    if unknown:
        ap.error(f"unknown method(s) {unknown}; known: {', '.join([*METHODS, LEARNED])}")
    trajectories = parse_trajectories(args.trajectories)
    if LEARNED in methods and args.model is None and set(parse_trajectories(args.train)) & set(trajectories):
        ap.error("--train and --trajectories overlap: the model must not see a test trajectory")
    seeds = [int(x) for x in args.seeds.split(",")]
    table: dict[tuple[str, str], dict[int, list[dict]]] = {}
    for seed in seeds:
        if LEARNED in methods:
            model = None if args.model is None else args.model.format(seed=seed)
            if model is None:
                model = args.model_out.format(seed=seed)
                Path(model).parent.mkdir(parents=True, exist_ok=True)
                status = train_dvl_model(parse_trajectories(args.train), {
                    "gnss_s": args.train_gnss_s, "seed": seed, "anomalies": args.train_anomalies,
                    "anomalies_from_s": 0.0}, seed, model)
                print(f"{LEARNED}: trained on trajectories {args.train} (GNSS {args.train_gnss_s:g} s, anomalies "
                      f"{args.train_anomalies!r}, seed {seed}): {status['trainer']}; model {model}", flush=True)
            METHODS[LEARNED] = learned_method(model)
        conditions = []
        base = {"gnss_s": args.gnss_s, "seed": seed}
        if args.anomalies:
            conditions.append(("anomalies", base | {"anomalies": args.anomalies, "anomalies_from_s":
                                                    args.anomalies_from_s if args.anomalies_from_s is not None
                                                    else args.gnss_s}))
        if not args.anomalies or args.also_clean:
            conditions.append(("clean", base))
        for condition, options in conditions:
            title = (f"A-KIT, derived GNSS during the first {args.gnss_s:g} s, seed {seed}, "
                     + (f"DVL anomalies {args.anomalies!r}" if condition == "anomalies" else "clean DVL"))
            for name, rows in run_condition(trajectories, methods, options, title).items():
                table.setdefault((condition, name), {})[seed] = rows
    if len(seeds) > 1:
        print_summary(table, seeds)


if __name__ == "__main__":
    main()
