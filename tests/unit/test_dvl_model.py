"""DVL and depth measurement models (zennav.nav.aid.dvl, .depth) against numerical differentiation, the beam geometry
(zennav.nav.beams) and its partial-beam cases, and the input checks with their counted reasons."""
from __future__ import annotations

import math

import numpy as np
import pytest

from zennav.nav.beams import (
    BEAM_CASES,
    beam_case,
    beams_from_velocity,
    janus_directions,
    reconstruct_beams,
    velocity_from_beams,
)
from zennav.nav.navigator import Navigator
from zennav.nav.types import NS, DepthSample, DvlSample, InitialState, NavConfig

T0 = 1_000 * NS


def _nav(**kw) -> Navigator:
    cfg = NavConfig(has_dvl=True, has_depth=True, dvl_lever_b=(1.2, -0.3, 0.5),
                    dvl_mount_euler=(0.02, -0.03, math.radians(45.0)), **kw)
    init = InitialState(T0, np.array([0.5, 1.0, -20.0]), np.array([1.5, -0.8, 0.2]),
                        np.array([0.05, -0.04, 1.0]))
    nav = Navigator(cfg, init)
    nav.on_imu(T0 + NS // 100, [0.002, -0.001, 0.003], [0.01, 0.02, -0.0981])  # a body rate for the lever arm
    n = nav.n_states
    dx = np.zeros(n)
    dx[15:] = np.linspace(-0.03, 0.02, n - 15)  # non-zero beam biases, scale factor, depth bias
    nav.feedback(dx)
    return nav


def _numeric_H(nav: Navigator, f, eps=1e-6) -> np.ndarray:
    """-(f(x corrected by +eps e_j) - f(x corrected by -eps e_j)) / (2 eps): with dx = estimate minus truth,
    f(truth) = f(estimate) - H dx."""
    state = nav.get_state()
    cols = []
    for j in range(nav.n_states):
        vals = []
        for sign in (1.0, -1.0):
            nav.set_state(state)
            dx = np.zeros(nav.n_states)
            dx[j] = sign * eps
            nav.feedback(dx)
            vals.append(f(nav))
        cols.append(-(vals[0] - vals[1]) / (2.0 * eps))
    nav.set_state(state)
    return np.column_stack(cols)


def test_tight_beam_jacobian_matches_numerical_differentiation():
    """H of the beams (attitude, velocity, gyro bias through the lever arm, beam biases, scale factor) is the
    derivative of the predicted beams (1 + k) B C_db (C_bn v_n + omega_nb_b x l_b) + bias."""
    nav = _nav()
    src = nav.sources["dvl"]
    _, H = src.model(nav)
    H_num = _numeric_H(nav, lambda n: src.model(n)[0])
    assert H.shape == (4, nav.n_states)
    np.testing.assert_allclose(H, H_num, atol=2e-6)
    assert np.abs(H[:, src.scale]).max() > 0.5 and np.array_equal(H[:, src.bias], np.eye(4))


def test_loose_and_depth_jacobians_match_numerical_differentiation():
    nav = _nav(dvl_mode="loose")
    src = nav.sources["dvl_loose"]
    _, H_v = src.velocity(nav)
    np.testing.assert_allclose(H_v, _numeric_H(nav, lambda n: src.velocity(n)[0]), atol=2e-6)
    dep = nav.sources["depth"]

    def predicted_depth(n):
        return np.array([n.config.depth_surface_h_m - n.state.h + n.aug_value(dep.bias)[0]])

    H = np.zeros((1, nav.n_states))
    H[0, 2], H[0, dep.bias] = 1.0, 1.0
    np.testing.assert_allclose(H, _numeric_H(nav, predicted_depth), atol=1e-6)


@pytest.mark.parametrize("layout", ["+", "x"])
def test_beams_velocity_round_trip_and_reconstruction(layout):
    B = janus_directions(math.radians(30.0), layout)
    rng = np.random.default_rng(1)
    v_d = rng.normal(size=3)
    beams = beams_from_velocity(v_d, B)
    np.testing.assert_allclose(velocity_from_beams(beams, np.ones(4, bool), B), v_d, atol=1e-12)
    for missing in range(4):  # 3 beams: exact
        valid = np.ones(4, bool)
        valid[missing] = False
        assert beam_case(valid) == "3"
        np.testing.assert_allclose(reconstruct_beams(np.where(valid, beams, 99.0), valid), beams, atol=1e-12)
        np.testing.assert_allclose(velocity_from_beams(np.where(valid, beams, 99.0), valid, B), v_d, atol=1e-12)
    v_level = np.array([v_d[0], v_d[1], 0.0])  # 2 adjacent beams: exact only without vertical velocity
    level = beams_from_velocity(v_level, B)
    for pair in ((0, 1), (1, 2), (2, 3), (3, 0)):
        valid = np.isin(np.arange(4), pair)
        assert beam_case(valid) == "2_orthogonal"
        np.testing.assert_allclose(reconstruct_beams(np.where(valid, level, 99.0), valid), level, atol=1e-12)
        np.testing.assert_allclose(velocity_from_beams(level, valid, B), v_level, atol=1e-12)
        assert not np.allclose(reconstruct_beams(beams, valid), beams)  # heave breaks the assumption
    for valid, case in (([1, 0, 1, 0], "2_parallel"), ([0, 1, 0, 1], "2_parallel"), ([0, 0, 1, 0], "1"),
                        ([0, 0, 0, 0], "0")):
        assert beam_case(valid) == case
        assert reconstruct_beams(beams, np.array(valid, bool)) is None
        assert velocity_from_beams(beams, np.array(valid, bool), B) is None
    assert set(BEAM_CASES) == {"4", "3", "2_orthogonal", "2_parallel", "1", "0"}


def _beams_at(nav, src, valid=(1, 1, 1, 1), offset=0.0) -> DvlSample:
    predicted, _ = src.model(nav)
    return DvlSample(nav.t_ns, predicted + offset, np.array(valid, bool))


def test_partial_beam_cases_are_counted_and_tight_fuses_the_valid_beams():
    nav = _nav()
    src = nav.sources["dvl"]
    t = nav.t_ns
    for k, (valid, case, fused) in enumerate((([1, 1, 1, 1], "4", True), ([1, 1, 0, 1], "3", True),
                                             ([1, 1, 0, 0], "2_orthogonal", True), ([1, 0, 1, 0], "2_parallel", True),
                                             ([0, 0, 1, 0], "1", True), ([0, 0, 0, 0], "0", False))):
        nav.on_imu(t + (k + 2) * NS // 100, [0.0, 0.0, 0.0], [0.0, 0.0, -0.0981])
        sample = _beams_at(nav, src, valid, 0.01)
        assert nav.on_aid("dvl", sample) is fused
        assert nav.counters[f"dvl_beams_{case}"] == 1
        rep = nav.pop_reports()[-1]
        assert f"beams_{case}" in rep.faults and len(rep.innovation) == sum(valid) and rep.fused is fused
    assert rep.reason == "dvl_beams_0" and "predicted" in rep.faults


def test_trial_features_do_not_fuse_and_correction_is_subtracted():
    nav = _nav(vb_dvl=True)
    src = nav.sources["dvl"]
    sample = _beams_at(nav, src, (1, 1, 0, 1), np.array([0.05, 0.0, 0.0, 0.0]))
    before = nav.get_state()
    feats = src.trial(nav, sample)
    assert nav.get_state()["nav"] == before["nav"] and nav.get_state()["P"] == before["P"]
    assert src.vb.count == 0
    assert feats.case == "3" and feats.kind == ("measured", "measured", "reconstructed", "measured")
    obs = sample.beams
    np.testing.assert_allclose(feats.observed[2], obs[1] + obs[3] - obs[0], atol=1e-12)  # the Janus reconstruction
    np.testing.assert_allclose(feats.innovation, feats.predicted - feats.observed, atol=1e-12)
    np.testing.assert_allclose(feats.innovation[[0, 1, 3]], [-0.05, 0.0, 0.0], atol=1e-9)
    assert feats.mahalanobis > 0 and np.all(feats.R_diag > 0)
    assert src.fuse(nav, sample, correction=np.array([0.05, 0.0, 0.0, 0.0]))
    rep = nav.pop_reports()[-1]
    np.testing.assert_allclose(rep.innovation, 0.0, atol=1e-9)
    assert "corrected" in rep.faults and src.vb.count == 1 and src.vb.last.R.shape == (3, 3)


def test_bad_input_is_rejected_with_counted_reasons():
    nav = _nav()
    t = nav.t_ns
    ok = _beams_at(nav, nav.sources["dvl"])
    bad = [
        (DvlSample(t, np.array([np.nan, 0.4, -0.5, -0.4]), np.ones(4, bool)), "dvl_nonfinite"),
        (DvlSample(t, np.array([50.0, 0.4, -0.5, -0.4]), np.ones(4, bool)), "dvl_malformed"),
        (DvlSample(t, np.array([0.5, 0.4]), np.ones(2, bool)), "dvl_malformed"),
        (DvlSample(t),  "dvl_malformed"),
    ]
    for sample, reason in bad:
        assert nav.on_aid("dvl", sample) is False
        assert nav.counters[reason] >= 1
    assert nav.on_aid("dvl", DvlSample(t, np.where([0, 1, 1, 1], ok.beams, np.nan), np.array([0, 1, 1, 1], bool)))
    assert nav.on_aid("dvl", ok) is False and nav.counters["dvl_out_of_order"] == 1
    assert nav.on_aid("dvl", DvlSample(t - NS, ok.beams, ok.beam_valid)) is False
    assert nav.on_aid("depth", DepthSample(t, float("inf"))) is False and nav.counters["depth_nonfinite"] == 1
    assert nav.on_aid("depth", DepthSample(t - NS, 20.0)) is False and nav.counters["depth_stale"] == 1
    assert nav.on_aid("depth", DepthSample(t, 20.0)) is True


def test_no_dvl_data_no_sources_no_states():
    """A configuration without DVL or depth data runs neither source (plain replays unchanged)."""
    nav = Navigator(NavConfig(), InitialState(T0, np.array([0.5, 1.0, 0.0]), np.zeros(3), np.zeros(3)))
    assert "dvl" not in nav.sources and "depth" not in nav.sources and nav.n_states == 15
    nav = _nav(dvl_mode="off", depth=False)
    assert not {"dvl", "dvl_loose", "depth"} & set(nav.sources)
