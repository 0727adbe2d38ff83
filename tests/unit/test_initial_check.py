"""The configured initial state tested against the first GNSS fixes (zennav.nav.alignment, Alignment.check_initial,
issue 18): a stale one (the data's start cut, the state left as it was) has its position and velocity reset from the
fixes, then its attitude rejected once the fixes in motion contradict it, and the engine aligns in motion; a correct
one, and a correct one whose first fix is an outlier, are accepted; one at rest waits for the first fixes in motion (a
heading given wrong at rest: tests/unit/test_alignment.py); a wrong position or velocity with the attitude right is
reset from the fixes and the attitude kept."""
from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from zennav.metrics import ned_errors
from zennav.nav.alignment import AT_REST
from zennav.nav.navigator import Navigator
from zennav.nav.rotation import quat_to_euler, wrap_angle
from zennav.nav.types import NS, Dataset, InitialState
from zennav.replay import run_replay
from zennav.sim.scenarios import make_dataset

CUT_S = 60.0  # the car drives at this time of the seed-1 drive (asserted)


@pytest.fixture(scope="module")
def drive() -> Dataset:
    return make_dataset("car", duration_s=150.0, imu_rate_hz=100.0, gnss_rate_hz=1.0, seed=1)


def cut(ds: Dataset, cut_s: float, initial: InitialState | None = None) -> Dataset:
    """ds without its first cut_s seconds of IMU and GNSS; its initial state (default: left as it was, what a user
    does who moves a file's start but forgets the initial state) at the new first IMU sample."""
    t_cut = int(ds.imu.t_ns[0]) + int(cut_s * NS)
    imu = ds.imu.slice(ds.imu.t_ns >= t_cut)
    start = replace(ds.initial if initial is None else initial, t_ns=int(imu.t_ns[0]))
    return replace(ds, imu=imu, gnss=ds.gnss.slice(ds.gnss.t_ns > t_cut), initial=start,
                   config=ds.config.with_(start_t_ns=start.t_ns))


def truth_state(ds: Dataset, cut_s: float) -> InitialState:
    """The truth at cut_s [s] of the drive with the drive's configured 1-sigma (a correct initial state there)."""
    k = int(np.searchsorted(ds.truth.t_ns, int(ds.imu.t_ns[0]) + int(cut_s * NS)))
    assert ds.truth.v_n is not None and ds.truth.euler is not None
    return replace(ds.initial, llh=ds.truth.llh[k], v_n=ds.truth.v_n[k], euler=ds.truth.euler[k])


def horizontal_errors(ds: Dataset, res) -> np.ndarray:
    k = np.searchsorted(ds.truth.t_ns, res.t_ns)
    e = ned_errors(res.llh, ds.truth.llh[k])
    return np.hypot(e[:, 0], e[:, 1])


def test_stale_initial_state_is_rejected_and_the_run_aligns_in_motion(drive):
    truth_v = drive.truth.v_n[np.searchsorted(drive.truth.t_ns, int(drive.imu.t_ns[0]) + int(CUT_S * NS))]
    assert math.hypot(truth_v[0], truth_v[1]) > 3.0  # moving at the cut: in-motion alignment at once
    ds = cut(drive, CUT_S)
    res = run_replay(ds)
    counters, al = res.status["counters"], res.status["alignment"]
    # the car turned during the cut: position and velocity reset first, then the attitude discarded
    assert counters["init_state_reset_pos_vel"] == 1
    assert counters["init_state_rejected"] == 1 and counters["align_in_motion"] == 1
    assert al["initial_state"].startswith("rejected: ") and al["state"] == "aligned"
    assert counters.get("gate_reset", 0) == 0
    err = horizontal_errors(ds, res)
    after = res.t_ns >= al["times_ns"]["fine"]
    assert err[~after].max() > 100.0  # the stale state: a minute of driving away
    assert err[after].max() < 3.0 and np.sqrt(np.mean(err[after] ** 2)) < 1.0  # 0.5 m GNSS noise


def test_correct_initial_state_is_accepted(drive):
    ds = cut(drive, CUT_S, truth_state(drive, CUT_S))
    res = run_replay(ds)
    assert res.status["alignment"]["initial_state"] == "accepted"
    assert "init_state_rejected" not in res.status["counters"]
    assert horizontal_errors(ds, res).max() < 3.0


def test_correct_state_without_gnss_velocity_is_accepted_by_the_fix_pair(drive):
    """The velocity test from the displacement between two fixes (no velocity in them)."""
    ds = cut(drive, CUT_S, truth_state(drive, CUT_S))
    ds.gnss = replace(ds.gnss, v_n=None, std_v_n=None)
    res = run_replay(ds)
    assert res.status["alignment"]["initial_state"] == "accepted"


def test_state_at_rest_waits_for_motion():
    """The simulated car stands still first: its state is consistent with the fixes at rest and tested again once
    moving."""
    ds = make_dataset("car", duration_s=20.0, imu_rate_hz=100.0, gnss_rate_hz=1.0, seed=2)
    res = run_replay(ds)
    assert res.status["alignment"]["initial_state"] == AT_REST


def test_wrong_velocity_is_reset_from_the_fixes_velocity(drive):
    """Position right at the first fix (10 ms after the start), velocity reversed, attitude right: the fix's velocity
    strikes first, position and velocity are reset from the fixes, and the attitude kept passes once tested."""
    start = truth_state(drive, CUT_S - 0.01)
    ds = cut(drive, CUT_S - 0.01, replace(start, v_n=-start.v_n))
    res = run_replay(ds)
    counters = res.status["counters"]
    assert counters["init_state_reset_pos_vel"] == 1 and "init_state_rejected" not in counters
    assert res.status["alignment"]["initial_state"] == "accepted"
    assert horizontal_errors(ds, res)[-100:].max() < 3.0


def test_wrong_position_is_reset_and_the_attitude_kept(drive):
    """The truth's velocity and attitude at the cut, the position 200 m off: position and velocity are reset from the
    second fix, the attitude and its covariance are kept as they were (not re-aligned), and the state is accepted
    once the velocity has changed."""
    start = truth_state(drive, CUT_S)
    ds = cut(drive, CUT_S, replace(start, llh=start.llh + [200.0 / 6.4e6, 0.0, 0.0]))
    nav = Navigator(ds.config, ds.initial)
    k_fix, reset_fix = 0, None
    for k in range(len(ds.imu)):  # fixes queued as they come, fused when the IMU reaches their time
        t = int(ds.imu.t_ns[k])
        while k_fix < len(ds.gnss) and ds.gnss.t_ns[k_fix] <= t:
            nav.on_gnss(ds.gnss.fix_at(k_fix))
            k_fix += 1
        euler_before, P_att = quat_to_euler(nav.state.q_nb), nav.P[6:9, 6:9].copy()
        nav.on_imu(t, ds.imu.dtheta[k], ds.imu.dvel[k])
        if reset_fix is None and nav.counters.get("init_state_reset_pos_vel"):  # in this IMU interval
            reset_fix = k_fix
            assert np.abs(wrap_angle(quat_to_euler(nav.state.q_nb) - euler_before)).max() < 5e-3  # a 10 ms step
            assert np.allclose(nav.P[6:9, 6:9], P_att, rtol=1e-3, atol=1e-12)  # not the coarse alignment's 104 deg
            assert not nav.alignment.coarse
    assert reset_fix == 2  # the second fix in a row that contradicts the position
    assert nav.alignment.initial_check == "accepted" and "init_state_rejected" not in nav.counters
    assert "align_in_motion" not in nav.counters


def test_one_outlier_first_fix_does_not_reject_a_correct_state(drive):
    ds = cut(drive, CUT_S, truth_state(drive, CUT_S))
    llh = ds.gnss.llh.copy()
    llh[0, 0] += 50.0 / 6.4e6  # the first fix 50 m north
    ds.gnss = replace(ds.gnss, llh=llh)
    res = run_replay(ds)
    counters = res.status["counters"]
    assert res.status["alignment"]["initial_state"] == "accepted" and "init_state_rejected" not in counters
    assert counters["gnss_pos_jump"] == 1
    assert Navigator(ds.config, ds.initial).status()["alignment"]["initial_state"] == ""  # untested before a fix


def test_check_state_round_trips_through_get_state(drive):
    """A checkpoint taken while the state is under test (one contradicting fix seen) restores bit for bit."""
    ds = cut(drive, CUT_S)
    a, b = Navigator(ds.config, ds.initial), Navigator(ds.config, ds.initial)
    a.on_gnss(ds.gnss.fix_at(0))
    for k in range(int(np.searchsorted(ds.imu.t_ns, ds.gnss.t_ns[0] + NS // 2))):
        a.on_imu(int(ds.imu.t_ns[k]), ds.imu.dtheta[k], ds.imu.dvel[k])
    assert a.alignment.checking and a.alignment.check_strike.startswith("position NIS")
    b.set_state(a.get_state())
    assert b.get_state() == a.get_state()


def test_replay_of_stale_kf_gins_files_says_so(drive, tmp_path):
    """KF-GINS files whose starttime was moved CUT_S later with the initial state kept: the replay's GNSS line and
    the status record (metrics.json) say that the state was rejected."""
    from click.testing import CliRunner

    from zennav.cli import main
    from zennav.datasets import kfgins

    stale = replace(drive, initial=replace(drive.initial, t_ns=drive.initial.t_ns + int(CUT_S * NS)))
    yaml_path = kfgins.write_dataset(stale, tmp_path)
    res = CliRunner().invoke(main, ["replay", str(yaml_path), "--out", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    assert "the configured initial state was rejected by the first fixes" in res.output
    engine = json.loads((tmp_path / "out" / "metrics.json").read_text())["engine"]
    assert engine["alignment"]["initial_state"].startswith("rejected: ")
    assert engine["counters"]["init_state_reset_pos_vel"] == 1 and engine["counters"]["init_state_rejected"] == 1


def test_wrong_heading_in_motion_is_discarded_after_the_reset(drive):
    """Position and velocity right at the cut (the car driving), the heading 120 deg off: the fixes contradict the
    velocity it integrates, position and velocity are reset (attitude kept), the next fixes contradict the attitude and
    the engine aligns in motion."""
    start = truth_state(drive, CUT_S)
    ds = cut(drive, CUT_S, replace(start, euler=start.euler + [0.0, 0.0, math.radians(120.0)]))
    res = run_replay(ds)
    counters, al = res.status["counters"], res.status["alignment"]
    assert counters["init_state_reset_pos_vel"] == 1 and counters["init_state_rejected"] == 1
    assert al["method"] == "in_motion" and al["initial_state"].startswith("rejected: ")
    err = horizontal_errors(ds, res)
    assert err[res.t_ns >= al["times_ns"]["fine"]].max() < 3.0
