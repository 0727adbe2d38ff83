"""The variational-Bayes R (zennav.nav.vbkf) on a synthetic problem, and the DVL sources on the simulated AUV
(sim:auv through zennav.replay, the product's own path): tight beats pure INS under water by a large factor and the
loose baseline, its DVL error states are consistent with the injected ones, and the partial-beam cases are counted."""
from __future__ import annotations

import numpy as np
import pytest

from zennav.datasets.registry import load_dataset
from zennav.nav import earth
from zennav.nav.navigator import Navigator
from zennav.nav.vbkf import VariationalR
from zennav.params import load_filter_params, nav_config
from zennav.replay import run_replay


def _vb_track(R_true_steps, n_each: int, seed: int = 0) -> np.ndarray:
    """A static 2-D state measured directly with noise R_true (diagonal variances, one per segment of n_each
    samples), nominal R = I; a plain KF with the VB R. Returns the VB R diagonal after each update (N, 2)."""
    rng = np.random.default_rng(seed)
    vb = VariationalR(forgetting=0.97, iterations=3, floor=1e-3, ceiling=1e3)
    x_true = np.array([3.0, -1.0])
    x, P = np.zeros(2), np.eye(2) * 100.0
    out = []
    for R_true in R_true_steps:
        for _ in range(n_each):
            P = P + np.eye(2) * 1e-4
            z = x_true + np.sqrt(R_true) * rng.standard_normal(2)
            nu = x - z  # predicted minus observed, H = I
            R = vb.update(nu, P, np.eye(2))
            K = P @ np.linalg.inv(P + R)
            x = x - K @ nu
            P = (np.eye(2) - K) @ P
            out.append(np.diag(R))
    return np.array(out)


def test_vb_r_converges_to_the_true_r_and_tracks_a_step():
    R1, R2 = np.array([0.25, 4.0]), np.array([2.5, 0.5])
    track = _vb_track([R1, R2], 600)
    np.testing.assert_allclose(track[300:600].mean(axis=0), R1, rtol=0.15)
    np.testing.assert_allclose(track[900:].mean(axis=0), R2, rtol=0.15)
    assert np.all(np.abs(track[700:800].mean(axis=0) / R2 - 1.0) < 0.3)  # within ~100 samples of the step


def test_vb_features_exposed_and_solve_does_not_commit():
    vb = VariationalR()
    res = vb.solve(np.array([0.3, -0.1]), np.eye(2) * 0.01, np.eye(2) * 0.04, channels=(1, 3))
    assert vb.params == {} and vb.count == 0
    S = np.eye(2) * 0.01 + res.R
    assert res.mahalanobis == pytest.approx(float(res.innovation @ np.linalg.solve(S, res.innovation)))
    vb.commit(res)
    assert set(vb.params) == {"1", "3"} and vb.last is res and res.R_diag[0] > 0.04  # a large innovation inflates R
    state = vb.get_state()
    other = VariationalR()
    other.set_state(state)
    assert other.get_state() == state


@pytest.fixture(scope="module")
def auv():
    """A short AUV mission: 120 s at the surface with GNSS, then 140 s under water; a bottom loss of 10 s."""
    return load_dataset("sim:auv", duration_s=260.0, imu_rate_hz=50.0, dvl_bottom_loss="200:10")


def _run(ds, **settings):
    ds.config = nav_config(ds.config, load_filter_params()).with_(**settings)
    nav = Navigator(ds.config, ds.initial)
    res = run_replay(ds, navigator=nav)
    tr = ds.truth
    i = np.searchsorted(tr.t_ns, res.t_ns[-1])
    r_m, r_n = earth.radii(tr.llh[i, 0])
    d = res.llh[-1] - tr.llh[i]
    return nav, res, float(np.hypot(d[0] * (r_m + tr.llh[i, 2]), d[1] * (r_n + tr.llh[i, 2]) * np.cos(tr.llh[i, 0])))


def test_tight_dvl_beats_pure_ins_and_loose_with_consistent_dvl_states(auv):
    nav, res, err_tight = _run(auv, dvl_mode="tight")
    _, _, err_off = _run(auv, dvl_mode="off")
    _, res_loose, err_loose = _run(auv, dvl_mode="loose")
    under_water_s = (res.t_ns[-1] - auv.gnss.t_ns[-1]) / 1e9
    assert under_water_s > 130.0
    assert err_tight < 2.0 and err_off > 15.0 * err_tight, (err_tight, err_off)  # 0.56 m, 10.7 m
    assert err_tight < err_loose, (err_tight, err_loose)
    src = nav.sources["dvl"]
    injected = auv.notes["injected"]
    sigma = np.sqrt(np.diag(nav.P))
    bias_ratio = (nav.aug_value(src.bias) - injected["dvl_bias_mps"]) / sigma[src.bias]
    scale_ratio = (nav.aug_value(src.scale)[0] - injected["dvl_scale_error"]) / sigma[src.scale][0]
    assert np.all(np.abs(bias_ratio) < 3.0) and abs(scale_ratio) < 3.0, (bias_ratio, scale_ratio)
    assert sigma[src.scale][0] < 0.8 * nav.config.dvl_scale_std  # the scale factor was observed
    c = res.status["counters"]
    assert c["dvl_fused"] > 0.9 * len(auv.dvl) - c["dvl_beams_0"] - c.get("dvl_gate", 0) and c["depth_fused"] > 0
    assert c["dvl_beams_0"] == 50 and c["dvl_beams_3"] > 0  # 10 s of bottom loss at 5 Hz; the dropouts
    assert res_loose.status["counters"]["dvl_loose_fused"] > 0 and "dvl_fused" not in res_loose.status["counters"]


def test_vb_is_an_option_of_the_gnss_sources():
    ds = load_dataset("sim:static", duration_s=20.0)
    ds.config = ds.config.with_(vb_gnss=True)
    nav = Navigator(ds.config, ds.initial)
    res = run_replay(ds, navigator=nav)
    for name in ("gnss_pos", "gnss_vel"):
        vb = nav.sources[name].vb
        assert vb is not None and vb.count == res.status["counters"][f"{name}_fused"] > 10
        assert res.status["measurement_noise"][name]["vb_updates"] == vb.count
    assert all(s.vb is None for s in Navigator(ds.config.with_(vb_gnss=False), ds.initial).sources.values())


def test_vb_gate_rejects_an_outlier_without_learning_it():
    """With the engine's gate, an innovation outside it (against the predictive R) leaves the estimator unchanged
    and returns the current R, which the engine's gate then rejects; one inside is learned."""
    vb = VariationalR()
    HPHt, R_nom, gate = np.eye(2) * 0.01, np.eye(2) * 0.04, 13.8  # chi-square 0.999, 2 dof
    R = vb.update(np.array([2.0, 0.0]), HPHt, R_nom, (0, 1), gate)
    assert vb.count == 0 and vb.params == {} and np.allclose(R, R_nom)
    R = vb.update(np.array([0.5, 0.0]), HPHt, R_nom, (0, 1), gate)  # d2 = 5: inside, and large: R grows
    assert vb.count == 1 and R[0, 0] > R_nom[0, 0] and R[1, 1] < R_nom[1, 1]


def test_tight_dvl_finds_a_mounting_misalignment():
    """A DVL mounted 0.8 deg off in pitch and -1.5 deg in yaw from what the filter is told (sim:auv, exact truth):
    the misalignment states find pitch and yaw within 3 sigma, their sigma shrunk by the surface turns, and the
    position under water is better than without the states (dvl_mount_std 0). Beam biases small (0.002 m/s, and the
    filter told so): at a constant speed a yaw misalignment and beam biases are the same lateral velocity error
    (zennav.nav.aid.dvl), which the test of the beam-bias states above covers."""
    ds = load_dataset("sim:auv", duration_s=260.0, imu_rate_hz=50.0, dvl_bottom_loss="", dvl_outlier_prob=0.0,
                      dvl_bias_mps=0.002, dvl_misalignment_deg="0,0.8,-1.5")
    nav, _, err = _run(ds, dvl_bias_std_mps=0.002)
    _, _, err_without = _run(ds, dvl_bias_std_mps=0.002, dvl_mount_std=0.0)
    src = nav.sources["dvl"]
    assert src.mount == nav.aug_blocks["dvl_mount"]
    truth = np.radians(ds.notes["injected"]["dvl_misalignment_deg"])
    sigma = np.sqrt(np.diag(nav.P))[src.mount]
    ratio = (nav.aug_value(src.mount) - truth) / sigma
    assert np.all(np.abs(ratio[1:]) < 3.0), (np.degrees(nav.aug_value(src.mount)), np.degrees(sigma), ratio)
    assert np.all(sigma[1:] < 0.6 * nav.config.dvl_mount_std), np.degrees(sigma)  # pitch and yaw were observed
    assert err < 0.7 * err_without, (err, err_without)
    assert "dvl_mount" not in Navigator(ds.config.with_(dvl_mount_std=0.0), ds.initial).aug_blocks


def test_tight_dvl_estimates_the_dvl_time_offset():
    """DVL samples stamped 0.2 s after the motion they measure (sim:auv, exact truth): the time-offset state
    (dvl_delay_std_s > 0) finds 0.2 s within 3 sigma, its sigma shrunk from 0.5 s to under 0.1 s by the speed
    changes and turns; off (0, the default) it is not a state."""
    from dataclasses import replace

    from zennav.nav.types import NS

    ds = load_dataset("sim:auv", duration_s=260.0, imu_rate_hz=50.0, dvl_bottom_loss="", dvl_outlier_prob=0.0)
    ds.dvl = replace(ds.dvl, t_ns=ds.dvl.t_ns + int(0.2 * NS))
    nav, _, err = _run(ds, dvl_delay_std_s=0.5)
    src = nav.sources["dvl"]
    assert src.delay == nav.aug_blocks["dvl_delay"]
    tau, sigma = float(nav.aug_value(src.delay)[0]), float(np.sqrt(nav.P[src.delay.start, src.delay.start]))
    assert abs(tau - 0.2) < 3.0 * sigma and sigma < 0.1, (tau, sigma)
    assert err < 2.0, err
    assert "dvl_delay" not in Navigator(ds.config.with_(dvl_delay_std_s=0.0), ds.initial).aug_blocks
    other = Navigator(ds.config, ds.initial).sources["dvl"]  # a checkpoint carries the last DVL sample's v_d
    other.set_state(src.get_state())
    assert other.prev is not None and other.prev[0] == src.prev[0] and np.array_equal(other.prev[1], src.prev[1])
