"""What limits the clean drift on the A-KIT trajectories with the most turning (issue 14: T1 and T8 over 0.5 %), per
trajectory, against the reference (a Delph post-processed Phins solution aided by the same DVL: not independent,
zennav.datasets.akit). Figures, all from the last derived GNSS fix (--gnss-s) on, drift as % of the distance:
- ref v/p: the reference's own velocity, integrated (trapezoid), against the reference's positions: how far the
  reference is from self-consistent (a filter that matched its velocity exactly would drift this much);
- DVL DR: the DVL's dead reckoning with the reference attitude (akit_dvl.dvl_dead_reckoning), and the part of its
  final horizontal error [m] gathered in turns (|yaw rate| > TURN_RATE) and on the straights;
- residual fit: the DVL minus the reference's POSITION-derived body velocity (central differences of the positions
  at the IMU; the quantity whose integral is the drift), forward axis, least squares on [1, v_x, |yaw rate|,
  yaw rate, forward acceleration]: the |yaw rate| and yaw-rate coefficients [m/rad], acceleration [s] (a time skew
  tau shows as -tau), R^2; what no constant calibration (bias, scale) absorbs;
- turn term: the DVL's forward velocity less c |yaw rate|, c the mean of the other trajectories' |yaw rate|
  coefficients (leave-one-out), DR drift and tight EKF drift with it (a data-side test of whether that term is a
  general effect);
- tight EKF drift, and with the DVL time-offset state (NavConfig dvl_delay_std_s = --delay-std-s): its estimate and
  1-sigma at the end [s] (the filter's own check of the loader's DVL/IMU skew).

    .venv/bin/python benchmarks/akit_dvl_turns.py [--trajectories 1-13] [--gnss-s 60] [--delay-std-s 0.3]
"""
from __future__ import annotations

import argparse
import math
from dataclasses import replace

import numpy as np
from akit_dvl import METHODS, dvl_dead_reckoning, parse_trajectories, score

from zennav.datasets.registry import akit_specs, load_dataset
from zennav.nav import earth
from zennav.nav.aid.dvl import DvlTight
from zennav.nav.beams import beams_from_velocity, janus_directions
from zennav.nav.navigator import Navigator
from zennav.nav.rotation import euler_to_dcm
from zennav.nav.types import NS, Dataset
from zennav.replay import run_replay

TURN_RATE = math.radians(1.0)  # a DVL row with |yaw rate| above this is "in a turn" [rad/s]


def reference_consistency(ds: Dataset, t0_s: float) -> float:
    """Drift [%] of the reference's integrated velocity against its positions from t0_s [s] on."""
    tr = ds.truth
    assert tr is not None and tr.v_n is not None
    t = tr.t_ns / NS
    m = t >= t0_s
    ned = earth.llh_to_ned(tr.llh[m], tr.llh[m][0])
    v = tr.v_n[m]
    p = np.vstack([np.zeros(3), np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t[m])[:, None], axis=0)])
    dist = float(np.sum(np.linalg.norm(np.diff(ned[:, :2], axis=0), axis=1)))
    return 100.0 * float(np.hypot(*(p[-1] - ned[-1])[:2])) / dist


def dvl_residual(ds: Dataset) -> dict:
    """At the DVL rows inside the reference (its first and last row excluded): time [s], the DVL minus the
    reference's position-derived body velocity r (N, 3), that body velocity v_b, the yaw rate [rad/s], the forward
    acceleration [m/s^2] and C_nb (N, 3, 3) of the reference attitude."""
    tr, dvl = ds.truth, ds.dvl
    assert tr is not None and tr.euler is not None and dvl is not None and dvl.velocity_d is not None
    tt = tr.t_ns / NS
    v_pos = np.gradient(earth.llh_to_ned(tr.llh, tr.llh[0]), tt, axis=0)
    k = (dvl.t_ns > tr.t_ns[0]) & (dvl.t_ns < tr.t_ns[-1])
    t = dvl.t_ns[k] / NS
    euler = np.column_stack([np.interp(t, tt, np.unwrap(tr.euler[:, i])) for i in range(3)])
    C_nb = euler_to_dcm(euler)
    v_b = np.einsum("kji,kj->ki", C_nb, np.column_stack([np.interp(t, tt, v_pos[:, i]) for i in range(3)]))
    return {"t": t, "r": dvl.velocity_d[k] - v_b, "v_b": v_b, "yaw_rate": np.gradient(euler[:, 2], t),
            "accel": np.gradient(v_b[:, 0], t), "C_nb": C_nb}


def turn_split(res: dict, t0_s: float) -> tuple[float, float]:
    """Horizontal size [m] of the residual's integral in turns and on the straights from t0_s on."""
    m = res["t"] >= t0_s
    step = np.einsum("kij,kj->ki", res["C_nb"], res["r"]) * np.gradient(res["t"])[:, None]
    turn = np.abs(res["yaw_rate"]) > TURN_RATE
    return (float(np.hypot(*step[m & turn].sum(axis=0)[:2])), float(np.hypot(*step[m & ~turn].sum(axis=0)[:2])))


def forward_fit(res: dict, t0_s: float) -> tuple[np.ndarray, float]:
    """Least squares of the forward residual on [1, v_x, |yaw rate|, yaw rate, forward acceleration] from t0_s
    on: coefficients and R^2."""
    m = res["t"] >= t0_s
    X = np.column_stack([np.ones(m.sum()), res["v_b"][m, 0], np.abs(res["yaw_rate"][m]), res["yaw_rate"][m],
                         res["accel"][m]])
    y = res["r"][m, 0]
    coef = np.linalg.lstsq(X, y, rcond=None)[0]
    return coef, 1.0 - float(np.var(y - X @ coef) / np.var(y))


def without_turn_term(ds: Dataset, c: float) -> Dataset:
    """The dataset with the DVL's forward velocity less c |yaw rate| (the reference's yaw rate) and its beams
    recomputed (c [m/rad])."""
    tr, dvl = ds.truth, ds.dvl
    assert tr is not None and tr.euler is not None and dvl is not None and dvl.velocity_d is not None
    t = dvl.t_ns / NS
    yaw_rate = np.gradient(np.interp(t, tr.t_ns / NS, np.unwrap(tr.euler[:, 2])), t)
    v = dvl.velocity_d.copy()
    v[:, 0] -= c * np.abs(yaw_rate)
    B = janus_directions(ds.config.dvl_tilt, ds.config.dvl_layout)
    return replace(ds, dvl=replace(dvl, velocity_d=v, beams=beams_from_velocity(v, B)))


def delay_estimate(ds: Dataset, std_s: float) -> tuple[float, float, float]:
    """Tight EKF with the DVL time-offset state: (drift [%], estimate [s], 1-sigma [s]) at the end."""
    ds = replace(ds, config=ds.config.with_(dvl_mode="tight", vb_dvl=False, dvl_delay_std_s=std_s))
    nav = Navigator(ds.config, ds.initial)
    s = score(ds, run_replay(ds, navigator=nav))
    src = nav.sources["dvl"]
    assert isinstance(src, DvlTight) and src.delay is not None
    sl = src.delay
    return s["drift_pct"], float(nav.aug_value(sl)[0]), float(np.sqrt(nav.P[sl.start, sl.start]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trajectories", default=f"1-{len(akit_specs())}", help="e.g. 1-13 or 1,4,8")
    ap.add_argument("--gnss-s", type=float, default=60.0, help="derived GNSS during the first S seconds")
    ap.add_argument("--delay-std-s", type=float, default=0.3, help="prior 1-sigma of the DVL time-offset state [s]")
    args = ap.parse_args()
    data = {n: load_dataset(f"akit:Trajectory{n}", gnss_s=args.gnss_s) for n in parse_trajectories(args.trajectories)}
    t0 = {n: (int(ds.gnss.t_ns[-1]) if len(ds.gnss) else int(ds.initial.t_ns)) / NS for n, ds in data.items()}
    resid = {n: dvl_residual(ds) for n, ds in data.items()}
    fits = {n: forward_fit(resid[n], t0[n]) for n in data}
    turning = [n for n in data if np.mean(np.abs(resid[n]["yaw_rate"]) > TURN_RATE) > 0.1]  # fit c on these
    print(f"drift [%] from the last GNSS fix ({args.gnss_s:g} s); forward residual fit: |r| and r [m/rad], accel [s];"
          f" turn term c fitted on the other turning trajectories of {turning}")
    print(f"{'traj':<6}{'ref v/p':>8}{'DVL DR':>8}{'turn m':>8}{'str m':>7}{'|r|':>8}{'r':>8}{'accel':>7}{'R2':>6}"
          f"{'c':>7}{'DR-c':>7}{'EKF':>7}{'EKF-c':>7}{'EKF+tau':>8}{'tau s':>8}{'sigma':>7}")
    for n, ds in data.items():
        coef, r2 = fits[n]
        others = [fits[m][0][2] for m in turning if m != n]
        c = float(np.mean(others)) if others else 0.0
        corrected = without_turn_term(ds, c)
        turn_m, straight_m = turn_split(resid[n], t0[n])
        ekf = score(ds, METHODS["tight EKF"](ds))["drift_pct"]
        ekf_c = score(corrected, METHODS["tight EKF"](corrected))["drift_pct"]
        ekf_tau, tau, sigma = delay_estimate(ds, args.delay_std_s)
        print(f"T{n:<5}{reference_consistency(ds, t0[n]):>8.3f}{dvl_dead_reckoning(ds):>8.3f}{turn_m:>8.2f}"
              f"{straight_m:>7.2f}{coef[2]:>+8.3f}{coef[3]:>+8.3f}{coef[4]:>+7.3f}{r2:>6.2f}{c:>7.3f}"
              f"{dvl_dead_reckoning(corrected):>7.3f}{ekf:>7.3f}{ekf_c:>7.3f}{ekf_tau:>8.3f}{tau:>+8.3f}{sigma:>7.3f}",
              flush=True)


if __name__ == "__main__":
    main()
