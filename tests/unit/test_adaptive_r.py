"""Seed 001's innovation-based adaptive R: the estimator alone (SPD, bounds, tracking a step in noise), and in the
navigator on simulated drives: GNSS noise x10 for 60 s (adaptive vs fixed R) and a 50 m GNSS jump for 5 s."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2

from zennav.metrics import ned_errors
from zennav.nav import earth
from zennav.nav.adaptive_r import AdaptiveR
from zennav.nav.navigator import Navigator
from zennav.nav.types import NS
from zennav.sim.scenarios import make_dataset
from zennav.sim.sensors import antenna_truth

NEES_BAND = chi2.ppf([0.025, 0.975], 3)  # two-sided 95 % band of a 3-dof NEES


def test_estimate_stays_symmetric_positive_definite_and_bounded():
    rng = np.random.default_rng(11)
    est = AdaptiveR(3, window=5, forgetting=0.9, floor=0.5, ceiling=50.0)
    for k in range(3000):
        A = rng.normal(size=(3, 3))
        R_rep = A @ A.T + 1e-3 * np.eye(3)  # full, ill-conditioned reported R
        B = rng.normal(size=(3, 3)) * 10.0 ** rng.uniform(-3, 1)
        HPHt = B @ B.T
        scale = 10.0 ** rng.uniform(-3, 3)  # innovations far too small to far too large
        R = est.update(rng.normal(size=3) * scale, HPHt, R_rep)
        assert np.array_equal(R, R.T)
        L = np.linalg.cholesky(R_rep)
        ratio = np.linalg.eigvalsh(np.linalg.solve(L, np.linalg.solve(L, R).T))
        assert ratio.min() >= 0.5 * (1 - 1e-9) and ratio.max() <= 50.0 * (1 + 1e-9), (k, ratio)
    assert est.counts["inflate"] > 0 and est.counts["fading"] > 0  # both branches ran


def test_tracks_a_step_in_noise():
    """Innovations with R_true = R_rep, then 25 R_rep (noise x5), then R_rep again: the estimate follows."""
    rng = np.random.default_rng(12)
    R_rep = np.diag([0.25, 0.25, 1.0])
    HPHt = 0.1 * R_rep
    est = AdaptiveR(3, window=5, forgetting=0.95)
    phases = [(1.0, 300), (25.0, 300), (1.0, 300)]
    trace, branches = [], []
    for factor, n in phases:
        S_true = HPHt + factor * R_rep
        for _ in range(n):
            est.update(rng.multivariate_normal(np.zeros(3), S_true), HPHt, R_rep)
            trace.append(np.mean(est.status()["scale_diag"]))
            branches.append(est.branch)
    trace = np.array(trace)
    assert np.mean(trace[200:300]) == pytest.approx(1.0, abs=0.3)
    assert np.mean(trace[500:600]) == pytest.approx(25.0, rel=0.3)
    assert np.mean(trace[800:900]) == pytest.approx(1.0, abs=0.3)
    # The step up is caught by the inflation branch within a few innovations, not by the slow fading memory.
    assert "inflate" in branches[300:310] and trace[309] > 5.0


def noisy_gnss(ds, t0_s: float, t1_s: float, factor: float) -> None:
    """Multiply the simulated GNSS position and velocity errors by factor between t0_s and t1_s [s from start];
    the reported sigmas stay as they were (the receiver does not know)."""
    g = ds.gnss
    t_s = (g.t_ns - ds.imu.t_ns[0]) / NS
    llh_true, v_true = antenna_truth(ds.notes["trajectory"], t_s, ds.config.lever_arm_b)
    sel = (t_s >= t0_s) & (t_s < t1_s)
    g.llh[sel] = llh_true[sel] + factor * (g.llh[sel] - llh_true[sel])
    g.v_n[sel] = v_true[sel] + factor * (g.v_n[sel] - v_true[sel])


def run_nees(ds, **config):
    """Drive a Navigator over ds; every 0.1 s: position NEES (3 dof) and horizontal error [m]. Returns
    (fraction of NEES inside its 95 % band, horizontal RMS [m], horizontal max [m], navigator)."""
    nav = Navigator(ds.config.with_(**config), ds.initial)
    g, imu, truth = ds.gnss, ds.imu, ds.truth
    nees, horiz = [], []
    j = int(np.searchsorted(g.t_ns, ds.initial.t_ns, side="right"))
    for k in range(1, len(imu)):
        t = int(imu.t_ns[k])
        while j < len(g) and g.t_ns[j] <= t:
            nav.on_gnss(g.fix_at(j))
            j += 1
        nav.on_imu(t, imu.dtheta[k], imu.dvel[k])
        if k % 10 == 0:
            e = ned_errors(nav.state.llh[None], truth.llh[k][None])[0]
            nees.append(float(e @ np.linalg.solve(nav.P[:3, :3], e)))
            horiz.append(math.hypot(e[0], e[1]))
    nees, horiz = np.array(nees), np.array(horiz)
    in_band = float(np.mean((nees >= NEES_BAND[0]) & (nees <= NEES_BAND[1])))
    return in_band, float(np.sqrt(np.mean(horiz**2))), float(horiz.max()), nav


@pytest.mark.parametrize("seed", [0, 1])
def test_gnss_noise_x10_for_60s_adaptive_beats_fixed(seed):
    ds = make_dataset("car", duration_s=300.0, imu_rate_hz=100.0, gnss_rate_hz=1.0, seed=seed)
    noisy_gnss(ds, 120.0, 180.0, 10.0)
    fixed = run_nees(ds, adaptive_r=False)
    adaptive = run_nees(ds, adaptive_r=True)
    print(f"seed {seed}: NEES in 95 % band fixed {fixed[0]:.3f} adaptive {adaptive[0]:.3f}; horizontal RMS fixed "
          f"{fixed[1]:.2f} m adaptive {adaptive[1]:.2f} m")
    assert adaptive[0] > fixed[0] + 0.05
    assert adaptive[1] < 0.5 * fixed[1]
    # Fixed R rejects most noisy fixes, coasts and resets; adaptive R fuses them with an inflated R.
    assert fixed[3].counters["gate_reset"] > 0 and "gate_reset" not in adaptive[3].counters
    scale = adaptive[3].status()["measurement_noise"]["gnss_pos"]
    assert scale["inflate"] > 0 and max(scale["scale_diag"]) < 10.0  # back near the reported R at the end


@pytest.mark.parametrize("adaptive_r", [False, True])
def test_50m_jump_for_5s_is_rejected_and_filter_stays_consistent(adaptive_r):
    ds = make_dataset("car", duration_s=200.0, imu_rate_hz=100.0, gnss_rate_hz=1.0, seed=2)
    clean = run_nees(ds, adaptive_r=adaptive_r)
    g = ds.gnss
    t_s = (g.t_ns - ds.imu.t_ns[0]) / NS
    jumped = (t_s >= 100.0) & (t_s < 105.0)
    g.llh[jumped] += earth.dr_to_dllh(g.llh[jumped, 0], g.llh[jumped, 2]) * np.array([50.0, 0.0, 0.0])
    in_band, rms, worst, nav = run_nees(ds, adaptive_r=adaptive_r)
    print(f"adaptive_r={adaptive_r}: NEES in 95 % band {in_band:.3f} (no jump {clean[0]:.3f}); horizontal RMS "
          f"{rms:.3f} m (no jump {clean[1]:.3f}), max {worst:.2f} m (no jump {clean[2]:.2f})")
    jumps = [r for r in nav.pop_reports() if r.reason == "gnss_pos_jump"]
    assert sorted(r.t_ns for r in jumps) == sorted(g.t_ns[jumped].tolist())
    assert all(r.test_ratio > 1.0 and not r.fused for r in jumps)
    assert nav.counters["gnss_pos_jump"] == 5 and "gate_reset" not in nav.counters
    assert nav.counters["outage_declared"] == nav.counters["outage_recovered"] == 1  # 5 s without a fused fix
    assert in_band >= clean[0] - 0.01 and rms < 1.1 * clean[1] and worst < clean[2] + 0.3
    if adaptive_r:  # the jump did not leak into the R estimate
        assert max(nav.status()["measurement_noise"]["gnss_pos"]["scale_diag"]) < 3.0


def test_adaptive_r_switched_off_uses_the_reported_r():
    ds = make_dataset("car", duration_s=30.0, imu_rate_hz=100.0, gnss_rate_hz=1.0, seed=0)
    *_, nav = run_nees(ds)  # the default: off
    st = nav.status()
    assert st["adaptive_r"] is False
    reported = np.diag(np.square(np.maximum(ds.gnss.std_ned[-1], ds.config.pos_std_floor_m)))
    np.testing.assert_allclose(st["measurement_noise"]["gnss_pos"]["R"], reported)
    assert "scale_diag" not in st["measurement_noise"]["gnss_pos"]
