"""Vehicle constraints as aiding sources (zennav.nav.aid: vehicle.py, constraints.py, zupt.py, odometer.py) on the
simulator's exact truth: the vehicle-frame model and its Jacobian, standstill detection with hysteresis, ZUPT
holding the solution still, ZARU calibrating the gyro bias, the odometer's scale factor estimated, bad odometer
input counted, vehicle profiles parsed and applied, and the whole state restored mid-standstill."""
from __future__ import annotations

import math

import msgpack
import numpy as np
import pytest

from zennav.datasets.odometer import load_kfgins_odometer, write_kfgins_odometer
from zennav.datasets.registry import load_dataset, vehicle_of
from zennav.nav import earth
from zennav.nav.aid import OdometerSample
from zennav.nav.aid.vehicle import VehicleFrame
from zennav.nav.eskf import ATT, BG, N_STATES, VEL
from zennav.nav.navigator import Navigator
from zennav.nav.rotation import euler_to_quat, quat_multiply, rotvec_to_quat
from zennav.nav.strapdown import NavState
from zennav.nav.types import NS, NavConfig
from zennav.params import ParamError, constraint_flags, load_filter_params, load_profiles
from zennav.replay import run_replay
from zennav.replay_cli import filter_settings
from zennav.sim.scenarios import make_dataset, true_biases

STOP_S = 100.3  # the 150 s simulated car (seed 0) stands from 0 to 15.8 s and from 100.3 s to its end


@pytest.fixture(scope="module")
def car():
    return load_dataset("sim:car", duration_s=150.0)


def _state(v_n, euler) -> NavState:
    return NavState.from_arrays(np.array([0.5, 2.0, 30.0]), np.array(v_n, float), euler_to_quat(np.array(euler)))


def test_vehicle_frame_removes_the_mounting_and_the_lever_arm():
    """A car driving at 10 m/s: with its IMU yawed by 5 deg, the IMU frame sees a sideways velocity that the
    configured mounting removes; turning at 0.5 rad/s with the IMU 1 m ahead of the rear axle, the IMU moves
    sideways at 0.5 m/s and the axle (the configured lever arm) does not."""
    yaw, mount = 0.3, math.radians(5.0)
    s = _state([10.0 * math.cos(yaw), 10.0 * math.sin(yaw), 0.0], [0.0, 0.0, yaw + mount])
    omega_ib_b = s.C_nb.T @ earth.omega_ie_n(s.lat)
    plain = VehicleFrame(NavConfig())
    assert plain.velocity(s, omega_ib_b, N_STATES)[0][1] == pytest.approx(-10.0 * math.sin(mount), abs=1e-6)
    mounted = VehicleFrame(NavConfig(vehicle_mount_euler=(0.0, 0.0, -mount)))  # v in b: yawed by -5 deg
    np.testing.assert_allclose(mounted.velocity(s, omega_ib_b, N_STATES)[0], [10.0, 0.0, 0.0], atol=1e-6)
    s = _state(_state([0, 0, 0], [0.0, 0.0, yaw]).C_nb @ np.array([10.0, 0.5, 0.0]), [0.0, 0.0, yaw])
    omega_ib_b = np.array([0.0, 0.0, 0.5]) + s.C_nb.T @ earth.omega_ie_n(s.lat)
    assert plain.velocity(s, omega_ib_b, N_STATES)[0][1] == pytest.approx(0.5, abs=1e-5)
    axle = VehicleFrame(NavConfig(vehicle_lever_b=(-1.0, 0.0, 0.0)))
    np.testing.assert_allclose(axle.velocity(s, omega_ib_b, N_STATES)[0], [10.0, 0.0, 0.0], atol=1e-5)


def test_vehicle_frame_jacobian_matches_finite_differences():
    """H of v_v against the error state (velocity, attitude, gyro bias columns) with mounting and lever arm."""
    vf = VehicleFrame(NavConfig(vehicle_mount_euler=(0.02, -0.05, 0.1), vehicle_lever_b=(-1.2, 0.3, 0.8)))
    s = _state([8.0, -5.0, 0.3], [0.05, -0.03, 1.1])
    omega = np.array([0.1, -0.05, 0.4])
    v0, H = vf.velocity(s, omega, N_STATES + 2)
    assert H.shape == (3, N_STATES + 2) and not H[:, N_STATES:].any()

    def v_with_error(dx):
        q = quat_multiply(rotvec_to_quat(-dx[ATT]), s.q_nb)  # C_nb_hat = (I - [phi x]) C_nb
        s_err = NavState.from_arrays(np.array([s.lat, s.lon, s.h]), s.v_n + dx[VEL], q / np.linalg.norm(q))
        return vf.velocity(s_err, omega - dx[BG], N_STATES)[0]  # omega_hat = omega - dbg

    eps = 1e-5
    for col in [*range(VEL.start, VEL.stop), *range(ATT.start, ATT.stop), *range(BG.start, BG.stop)]:
        dx = np.zeros(N_STATES)
        dx[col] = eps
        numeric = (v_with_error(dx) - v_with_error(-dx)) / (2 * eps)  # central differences
        np.testing.assert_allclose(numeric, H[:, col], atol=1e-6, err_msg=f"column {col}")  # (v in omega_en_n: 1e-7)


def test_standstill_detection_with_hysteresis(car):
    """With GNSS and without (an outage over the second stop): updates only while the car truly stands, each stop
    detected once, entered zupt_enter_s after it began (hysteresis) and left within a second of the start."""
    config = car.config.with_(nhc=True, zupt=True)
    res = run_replay(car, outages=[(90.0, 60.0)], navigator=Navigator(config, car.initial))
    t0 = car.initial.t_ns
    speed = np.linalg.norm(car.truth.v_n, axis=1)
    z = [r for r in res.reports if r.source == "zupt"]
    t = np.array([r.t_ns for r in z])
    assert np.interp(t, car.truth.t_ns, speed).max() < 0.1
    assert res.status["counters"]["zupt_standstills"] == 2 and all(r.fused for r in z)
    second = (t - t0) / NS > 50.0
    first_s, second_s = (t[~second] - t0) / NS, (t[second] - t0) / NS
    assert first_s[0] >= config.zupt_enter_s and first_s[-1] < 15.8 + 1.0
    assert STOP_S + config.zupt_enter_s <= second_s[0] < STOP_S + config.zupt_enter_s + 1.0


def _standstill_drift_m(car, **constraints) -> float:
    res = run_replay(car, outages=[(90.0, 60.0)], navigator=Navigator(car.config.with_(**constraints), car.initial))
    t_s = (res.t_ns - car.initial.t_ns) / NS
    i = int(np.searchsorted(t_s, STOP_S + 2.0))
    d_n, d_e, _ = earth.dllh_to_ned(res.llh[-1] - res.llh[i], res.llh[i, 0], res.llh[i, 2])
    return math.hypot(d_n, d_e)


def test_zupt_holds_a_standing_car_still_without_gnss(car):
    held, drifting = _standstill_drift_m(car, nhc=True, zupt=True), _standstill_drift_m(car, nhc=True)
    assert held < 0.15 and held < 0.25 * drifting, (held, drifting)


def test_zaru_calibrates_the_gyro_bias():
    """A standing IMU without GNSS: ZARU (noise of the rate averaged over zupt_every_s, from the simulated ARW)
    brings the z gyro bias, which nothing else observes, from its 10 deg/h prior to a few deg/h, consistently."""
    ds = make_dataset("static", duration_s=150.0)
    got = {}
    for zaru in (False, True):
        config = ds.config.with_(zupt=True, zaru=zaru,
                                 zaru_std=ds.config.imu_noise.arw / math.sqrt(ds.config.zupt_every_s))
        nav = Navigator(config, ds.initial)
        run_replay(ds, outages=[(5.0, 145.0)], navigator=nav)
        got[zaru] = (nav.gyro_bias[2] - true_biases(ds).gyro_bias[-1, 2], math.sqrt(nav.P[11, 11]))
    prior = ds.config.imu_noise.gyro_bias_std
    assert got[False][1] > 0.9 * prior
    err, sigma = got[True]
    assert sigma < 0.35 * prior and abs(err) < 3.0 * sigma, (err, sigma, prior)


def test_odometer_scale_factor_is_estimated(car):
    """The simulated car's odometer reads 2 % fast: the scale-factor state finds it (error within 3 sigma, sigma
    a tenth of its 1 % prior) and the outage drift falls."""
    config = car.config.with_(nhc=True, zupt=True, odometer=True)
    nav = Navigator(config, car.initial)
    res = run_replay(car, outages=[(60.0, 30.0)], navigator=nav)
    sl = nav.aug_blocks["odo_scale"]
    k, sigma = float(nav.aug_value(sl)[0]), math.sqrt(nav.P[sl, sl][0, 0])
    assert sigma < 0.1 * config.odo_scale_std and abs(k - car.notes["odo_scale_error"]) < 3.0 * sigma, (k, sigma)
    counters = res.status["counters"]
    assert counters["odo_fused"] > 0.95 * len(car.odometer)
    assert not any(k.startswith("odo_") and k != "odo_fused" and k != "odo_gate" for k in counters)


def test_bad_odometer_input_is_counted_and_reported(car):
    nav = Navigator(car.config.with_(odometer=True), car.initial)
    for k in range(1, 400):
        nav.on_imu(int(car.imu.t_ns[k]), car.imu.dtheta[k], car.imu.dvel[k])
    t = nav.t_ns
    assert not nav.on_aid("odometer", OdometerSample(t - int(0.5 * NS), 0.0))
    assert nav.on_aid("odometer", OdometerSample(t, 0.0))
    assert not nav.on_aid("odometer", OdometerSample(t + 1, float("nan")))
    assert not nav.on_aid("odometer", OdometerSample(t + 2, 500.0))
    assert not nav.on_aid("odometer", OdometerSample(t - 5, 0.0))
    c = nav.counters
    assert (c["odo_fused"], c["odo_stale"], c["odo_malformed"], c["odo_out_of_order"]) == (1, 1, 2, 1)
    reasons = [r.reason for r in nav.pop_reports() if r.source == "odo"]
    assert reasons == ["odo_stale", "", "odo_malformed", "odo_malformed", "odo_out_of_order"]


def test_kfgins_odometer_file_round_trip(tmp_path, car):
    path = tmp_path / "ODO.txt"
    write_kfgins_odometer(path, car.odometer)
    back = load_kfgins_odometer(path)
    np.testing.assert_array_equal(back.t_ns, car.odometer.t_ns)
    np.testing.assert_allclose(back.speed_mps, car.odometer.speed_mps, atol=1e-6)


def test_comma2k19_has_rear_wheel_speeds():
    ds = load_dataset("comma2k19")
    assert ds.odometer is not None and len(ds.odometer) > 4000
    inside = (ds.odometer.t_ns > ds.gnss.t_ns[0]) & (ds.odometer.t_ns < ds.gnss.t_ns[-1])
    gnss_speed = np.interp(ds.odometer.t_ns[inside], ds.gnss.t_ns, np.hypot(ds.gnss.v_n[:, 0], ds.gnss.v_n[:, 1]))
    assert abs(np.mean(ds.odometer.speed_mps[inside] - gnss_speed)) < 0.5


def test_profiles_are_parsed_and_applied(tmp_path):
    assert {name: p.constraints for name, p in load_profiles().items()} == {
        "car": ("nhc", "zupt", "odo"), "multirotor": ("zupt",), "fixed-wing": (), "pedestrian": ("zupt",), "auv": ()}
    assert load_profiles()["auv"].settings == (("align_in_motion", "dvl"), ("align_min_speed_mps", 1.0),
                                               ("align_course_std", math.radians(5.0)))
    assert load_profiles()["multirotor"].settings == (("align_in_motion", "acceleration"),)
    assert constraint_flags(["zupt"]) == {"nhc": False, "zupt": True, "odometer": False}
    shipped = load_filter_params()
    assert not (shipped["nhc"] or shipped["zupt"] or shipped["odometer"])  # profile none: the switches, all off
    assert filter_settings("sim:car", None, "dataset", None) == {**shipped, "nhc": True, "zupt": True,
                                                                 "odometer": True}
    assert vehicle_of("ansfl:Horizontal/path_1") == "multirotor" and vehicle_of("sim:static") == "none"
    got = filter_settings("rtklibexplorer", None, "car", ["zupt"])  # the explicit list wins
    assert (got["nhc"], got["zupt"], got["odometer"]) == (False, True, False)
    with pytest.raises(ParamError, match="boat"):
        filter_settings("sim:car", None, "boat", None)
    with pytest.raises(ParamError, match="unknown constraint 'dvl'"):
        filter_settings("sim:car", None, None, ["dvl"])
    p = tmp_path / "ins.yaml"
    p.write_text("ins:\n  constraints:\n    profile: rover\n    vehicle_mount_euler: 0.0, -6.8, 5.4 deg\n"
                 "  profiles:\n    rover: [nhc, odo]\n")
    got = load_filter_params(p)
    assert (got["nhc"], got["zupt"], got["odometer"]) == (True, False, True)
    assert got["vehicle_mount_euler"] == (0.0, math.radians(-6.8), math.radians(5.4))
    # a profile's settings go over the file's sections; another profile named on the command line takes the
    # sections' values back
    p.write_text("ins:\n  alignment:\n    align_min_speed_mps: 3.0 m/s\n  constraints:\n    profile: sub\n"
                 "  profiles:\n    car: [nhc]\n    sub:\n      constraints: [zupt]\n"
                 "      align_min_speed_mps: 1.5 m/s\n      align_course_std: 4 deg\n")
    got = load_filter_params(p)
    assert (got["nhc"], got["zupt"], got["align_min_speed_mps"]) == (False, True, 1.5)
    assert got["align_course_std"] == pytest.approx(math.radians(4.0))
    got = filter_settings("sim:car", p, "car", None)
    assert (got["nhc"], got["zupt"], got["align_min_speed_mps"]) == (True, False, 3.0)
    assert "align_course_std" not in got
    assert filter_settings("akit:Trajectory1", None, "dataset", None)["align_min_speed_mps"] == 1.0
    for body, message in [("  constraints:\n    profile: boat\n", ":3: constraints.profile: unknown profile"),
                          ("  profiles:\n    sub:\n      align_min_speed_mps: 1 deg\n",
                           "profiles.sub.align_min_speed_mps: unit 'deg' where 'm/s'"),
                          ("  profiles:\n    sub:\n      top_speed: 1 m/s\n", ":3: profiles.sub.top_speed: not a"),
                          ("  profiles:\n    sub:\n      nhc: true\n", "profiles.sub.nhc: not a filter setting"),
                          ("  profiles:\n    sub: {constraints: nhc}\n", "a profile is a list"),
                          ("  profiles:\n    rover: [nhc, dvl]\n", ":3: profiles.rover: unknown constraint"),
                          ("  constraints:\n    vehicle_lever_b: 1, 2 m\n", "three finite numbers"),
                          ("  constraints:\n    vehicle_lever_b: 1, 2, 3 deg\n", "unit 'm' expected")]:
        p.write_text("ins:\n" + body)
        with pytest.raises(ParamError, match=message):
            load_filter_params(p)


def _outputs(ds, config, n: int, snap: int | None):
    """Packed solution and reports after each of IMU samples 1..n-1, GNSS withheld after 90 s and odometer samples
    fed as the replay does; with snap, the navigator is replaced after that sample by one restored from its
    msgpack round-tripped state."""
    nav = Navigator(config, ds.initial)
    t0, j, g, out = int(ds.imu.t_ns[0]), 0, 0, []
    odo = ds.odometer
    for k in range(1, n):
        t = int(ds.imu.t_ns[k])
        while g < len(ds.gnss) and ds.gnss.t_ns[g] <= t:
            if ds.gnss.t_ns[g] < t0 + 90 * NS:
                nav.on_gnss(ds.gnss.fix_at(g))
            g += 1
        nav.on_imu(t, ds.imu.dtheta[k], ds.imu.dvel[k])
        while j < len(odo) and odo.t_ns[j] <= t:
            nav.on_aid("odometer", OdometerSample(int(odo.t_ns[j]), float(odo.speed_mps[j])))
            j += 1
        if k == snap:
            state = msgpack.unpackb(msgpack.packb(nav.get_state()), strict_map_key=False)
            nav = Navigator(config, ds.initial)
            nav.set_state(state)
            assert state["sources"]["zupt"]["still"] and state["sources"]["zupt"]["window"]
        s = nav.solution()
        out.append(msgpack.packb([s.llh.tolist(), s.v_n.tolist(), s.q_nb.tolist(), s.gyro_bias.tolist(),
                                  [vars(r) for r in nav.pop_reports()]]))
    return out


def test_state_round_trip_mid_standstill(car):
    """NHC, ZUPT (detector window, hysteresis, its clock) and the odometer (its scale-factor state): restored in
    the second standstill, inside the outage, the run continues bit for bit."""
    config = car.config.with_(nhc=True, zupt=True, odometer=True)
    n, snap = int(103.0 * 200), int(102.0 * 200) + 7
    ref, got = _outputs(car, config, n, None), _outputs(car, config, n, snap)
    assert got == ref


def test_learned_forward_only_leaves_the_lateral_and_vertical_to_the_nhc(car):
    """With the NHC on and learn_forward_only, a learned body velocity changes the forward body velocity alone;
    without learn_forward_only its lateral and vertical outputs are fused as well."""
    from zennav.nav.learning import LearnQuery

    lateral = {}
    for forward_only in (False, True):
        config = car.config.with_(nhc=True, learning=True, learn_forward_only=forward_only, learn_where_better="off")
        nav = Navigator(config, car.initial)
        v_b0 = nav.state.C_nb.T @ nav.state.v_n
        sigma = float(nav.std_v_n.min())  # answers one sigma of the velocity away, as sure as the filter
        query = LearnQuery(nav.t_ns, "body_velocity", np.zeros(12), 1.0)
        assert nav.on_correction(query, v_b0 + sigma, np.full(3, sigma))
        dv_b = nav.state.C_nb.T @ nav.state.v_n - v_b0
        assert dv_b[0] > 0.2 * sigma
        lateral[forward_only] = np.abs(dv_b[1:])
    assert np.all(lateral[False] > 0.2 * sigma)
    np.testing.assert_allclose(lateral[True], 0.0, atol=0.01 * sigma)  # through P's correlations only


@pytest.mark.parametrize("where_better, nhc", [("on", False), ("nhc", True)])
def test_learned_where_better_fuses_only_the_outputs_the_model_knows_better(car, where_better, nhc):
    """With learn_where_better (on; nhc: under the non-holonomic constraint), a learned body-velocity output is
    fused only where its 1-sigma is below the filter's own 1-sigma of it: a sure forward and an unsure lateral and
    vertical answer move the forward body velocity alone; an answer unsure in every output is not fused (counted
    learned_body_velocity_weak)."""
    from zennav.nav.learning import LearnQuery

    config = car.config.with_(learning=True, learn_where_better=where_better, nhc=nhc)
    nav = Navigator(config, car.initial)
    v_b0 = nav.state.C_nb.T @ nav.state.v_n
    sigma = float(nav.std_v_n.min())
    query = LearnQuery(nav.t_ns, "body_velocity", np.zeros(12), 1.0)
    assert not nav.on_correction(query, v_b0 + sigma, np.full(3, 10.0 * sigma))
    assert nav.counters["learned_body_velocity_weak"] == 1
    np.testing.assert_allclose(nav.state.C_nb.T @ nav.state.v_n, v_b0, atol=1e-12)
    assert nav.on_correction(query, v_b0 + sigma, np.array([0.5, 10.0, 10.0]) * sigma)
    dv_b = nav.state.C_nb.T @ nav.state.v_n - v_b0
    assert dv_b[0] > 0.5 * sigma
    np.testing.assert_allclose(dv_b[1:], 0.0, atol=0.05 * sigma)  # through P's correlations only


def test_learned_where_better_nhc_applies_under_the_nhc_only(car):
    """learn_where_better nhc leaves an answer unsure in every output out under the non-holonomic constraint and
    fuses it without the constraint."""
    from zennav.nav.learning import LearnQuery

    for nhc in (True, False):
        nav = Navigator(car.config.with_(learning=True, learn_where_better="nhc", nhc=nhc), car.initial)
        sigma = float(nav.std_v_n.min())
        query = LearnQuery(nav.t_ns, "body_velocity", np.zeros(12), 1.0)
        v_b0 = nav.state.C_nb.T @ nav.state.v_n
        assert nav.on_correction(query, v_b0 + sigma, np.full(3, 10.0 * sigma)) is not nhc
        assert nav.counters["learned_body_velocity_weak"] == int(nhc)


def test_learned_held_error_does_not_shrink_with_the_number_of_answers(car):
    """Answers that share one offset (a model's bias held through the outage): taken as white, ten of them pull
    the forward body velocity most of the way to the offset; with learn_held_fraction 0.9 the bias state takes a
    part of the offset, the velocity moves about half as far and its variance stays several times larger. A fused
    GNSS fix restarts the held-error states at the next answer (value 0, uncorrelated, 1-sigma sqrt(0.9) std)."""
    from zennav.nav.learning import LearnQuery

    moved, var = {}, {}
    for held in (0.0, 0.9):
        nav = Navigator(car.config.with_(learning=True, learn_held_fraction=held), car.initial)
        v_b0 = nav.state.C_nb.T @ nav.state.v_n
        sigma = float(nav.std_v_n.max())  # each answer as sure as the filter
        query = LearnQuery(nav.t_ns, "body_velocity", np.zeros(12), 1.0)
        for _ in range(10):
            assert nav.on_correction(query, v_b0 + np.array([sigma, 0.0, 0.0]), np.full(3, sigma))
        moved[held] = float((nav.state.C_nb.T @ nav.state.v_n - v_b0)[0])
        C_bn = nav.state.C_nb.T
        var[held] = float(C_bn[0] @ nav.kf.P[VEL, VEL] @ C_bn[0])
    assert moved[0.0] > 0.8 * sigma and 0.0 < moved[0.9] < 0.65 * moved[0.0], moved
    assert var[0.9] > 3.0 * var[0.0], var
    sl = nav.aug_blocks["learned_bias"]
    assert nav.aug_value(sl)[0] > 0.3 * sigma  # the bias state took the offset
    g = int(np.searchsorted(car.gnss.t_ns, nav.t_ns, side="right"))  # the first fix after the start
    k = 1
    while nav.t_ns < car.gnss.t_ns[g]:
        nav.on_imu(int(car.imu.t_ns[k]), car.imu.dtheta[k], car.imu.dvel[k])
        k += 1
    nav.on_gnss(car.gnss.fix_at(g))  # fused at once (not newer than the engine)
    assert nav.last_fused_t_ns == int(car.gnss.t_ns[g]) and nav.aug_value(sl)[0] != 0.0
    query = LearnQuery(nav.t_ns, "body_velocity", np.zeros(12), 1.0)
    v_b = nav.state.C_nb.T @ nav.state.v_n
    P_before = nav.kf.P.copy()
    assert nav.on_correction(query, v_b, np.full(3, sigma))  # no offset: the restart is all that moves the bias
    np.testing.assert_allclose(nav.aug_value(sl), 0.0, atol=1e-9 * sigma)
    assert nav.kf.P[sl, sl][0, 0] < 0.9 * sigma**2 < P_before[sl, sl][0, 0] + 0.9 * sigma**2


def test_learned_lateral_sigma_is_floored_at_the_nhc_under_the_constraint(car):
    """With the NHC and learn_nhc_floor, a learned lateral answer claiming a 1-sigma far below the constraint's
    is fused with the constraint's (correlated_variance of nhc_std_mps over one answer period): it moves the
    lateral body velocity as an answer of that 1-sigma does without the floor."""
    from zennav.nav.aid.base import correlated_variance
    from zennav.nav.learning import BODY_EVERY_S, LearnQuery

    floor = math.sqrt(correlated_variance(car.config.nhc_std_mps, BODY_EVERY_S, car.config.nhc_corr_s))
    lateral = {}
    for nhc_floor, claimed in ((True, 0.01 * floor), (False, floor)):
        nav = Navigator(car.config.with_(nhc=True, learning=True, learn_nhc_floor=nhc_floor, learn_where_better="off"),
                        car.initial)
        v_b0 = nav.state.C_nb.T @ nav.state.v_n
        query = LearnQuery(nav.t_ns, "body_velocity", np.zeros(12), 1.0)
        assert nav.on_correction(query, v_b0 + np.array([0.0, 0.5, 0.0]), np.array([1.0, claimed, claimed]))
        lateral[nhc_floor] = float((nav.state.C_nb.T @ nav.state.v_n - v_b0)[1])
    assert 0.0 < lateral[True] < 0.5
    np.testing.assert_allclose(lateral[True], lateral[False], rtol=1e-9)


def test_learned_consistency_deweights_answers_that_scatter_beyond_their_sigma(car):
    """With learn_consistency, answers that scatter 4x beyond their claimed 1-sigma (seeded) are fused with an R
    grown from their innovations (counted learned_body_velocity_deweighted): the filter's body-velocity error
    ends consistent with its covariance (normalised error squared, 3 expected) less than 0.7 times as far off as
    with the claimed R (about 11 against 22); answers as good as they claim keep their R (within a factor 2) and the
    estimator's state survives a round trip."""
    from zennav.nav.learning import LearnQuery

    err, R_end, counted = {}, {}, {}
    for consistency, scatter in ((False, 4.0), (True, 4.0), (True, 1.0)):
        rng = np.random.default_rng(7)
        nav = Navigator(car.config.with_(learning=True, learn_consistency=consistency), car.initial)
        v_b0 = nav.state.C_nb.T @ nav.state.v_n
        sigma = float(nav.std_v_n.max())
        query = LearnQuery(nav.t_ns, "body_velocity", np.zeros(12), 1.0)
        for _ in range(20):
            nav.on_correction(query, v_b0 + scatter * sigma * rng.standard_normal(3), np.full(3, sigma))
        e_b = nav.state.C_nb.T @ nav.state.v_n - v_b0
        C_bn = nav.state.C_nb.T
        err[(consistency, scatter)] = float(e_b @ np.linalg.solve(C_bn @ nav.kf.P[VEL, VEL] @ C_bn.T, e_b))
        R_end[(consistency, scatter)] = float(nav.sources["learned_body_velocity"].R_used[0, 0]) / sigma**2
        counted[(consistency, scatter)] = nav.counters["learned_body_velocity_deweighted"]
    assert counted[(True, 4.0)] > 0 and counted[(False, 4.0)] == 0
    assert R_end[(True, 4.0)] > 4.0 and R_end[(False, 4.0)] == pytest.approx(1.0)
    assert err[(True, 4.0)] < 0.7 * err[(False, 4.0)], err
    assert R_end[(True, 1.0)] < 2.0, R_end
    src = nav.sources["learned_body_velocity"]
    state = msgpack.unpackb(msgpack.packb(src.get_state()))
    fresh = Navigator(car.config.with_(learning=True, learn_consistency=True), car.initial).sources[src.name]
    fresh.set_state(state)
    assert fresh.get_state() == src.get_state()
