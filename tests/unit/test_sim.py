"""Simulator: exact truth, ideal IMU increments, IMU/GNSS error statistics, datasets and reproducibility."""
from __future__ import annotations

import logging
import os
from collections import Counter

import numpy as np
import pytest

from zennav.nav import earth
from zennav.nav.rotation import (
    dcm_to_quat,
    dcm_to_rotvec,
    quat_multiply,
    quat_to_dcm,
    rotvec_to_quat,
    wrap_angle,
)
from zennav.nav.types import NS, FixType, ImuNoise
from zennav.sim import cache
from zennav.sim.scenarios import IMU_GRADES, make_dataset, true_biases
from zennav.sim.sensors import (
    antenna_truth,
    body_rates,
    gauss_markov,
    ideal_increments,
    simulate_gnss,
    simulate_imu,
)
from zennav.sim.trajectory import CarTrajectory, SmoothSteps, StaticTrajectory, make_trajectory

LLH0 = np.array([np.radians(30.53), np.radians(114.36), 30.0])
DT = 0.005


@pytest.fixture(scope="module", params=["car", "multirotor", "custom-car"])
def moving(request):
    """A 300 s drive or flight with turns, speed changes and (multirotor) tilts and yaw rotations; the custom
    car accelerates and climbs while it turns (overlapping transitions of different profiles)."""
    if request.param == "custom-car":
        speed = SmoothSteps(0.0, [5.0, 40.0], [10.0, 8.0], [15.0, -15.0])
        turn_rate = SmoothSteps(0.0, [8.0, 20.0, 30.0], [4.0, 4.0, 3.0], [0.2, -0.5, 0.3])
        grade = SmoothSteps(0.0, [6.0, 25.0], [8.0, 10.0], [0.05, -0.05])
        return CarTrajectory(LLH0, 300.0, speed, turn_rate, grade, yaw0=-2.0)
    return make_trajectory(request.param, 300.0, seed=3, start_llh=LLH0)


def _gl_integral(f, t_a, t_b, n_sub=2000, n_nodes=6, knots=()):
    """Composite Gauss-Legendre integral of f(t) -> (N, k) over [t_a, t_b], pieces split at the knots."""
    x, w = np.polynomial.legendre.leggauss(n_nodes)
    knots = np.asarray(knots, dtype=float)
    edges = np.union1d(np.linspace(t_a, t_b, n_sub + 1), knots[(knots > t_a) & (knots < t_b)])
    n_sub = len(edges) - 1
    half = 0.5 * np.diff(edges)
    t = (0.5 * (edges[1:] + edges[:-1])[:, None] + half[:, None] * x).ravel()
    return (f(t).reshape(n_sub, n_nodes, -1) * (w[None, :, None] * half[:, None, None])).sum(axis=(0, 1))


def _integrate_attitude(traj, edges, q_nb):
    """Two-sample (coning-corrected) attitude integration of the ideal dtheta with the n-frame rotation."""
    dtheta, _ = ideal_increments(traj, edges)
    st = traj.state(0.5 * (edges[1:] + edges[:-1]))
    omega_in_n = earth.omega_ie_n(st.llh[:, 0]) + earth.omega_en_n(st.llh[:, 0], st.llh[:, 2], st.v_n)
    prev = np.zeros(3)
    for k, dt in enumerate(np.diff(edges)):
        phi = dtheta[k] + np.cross(prev, dtheta[k]) / 12.0
        q_nb = quat_multiply(quat_multiply(rotvec_to_quat(-omega_in_n[k] * dt), q_nb), rotvec_to_quat(phi))
        prev = dtheta[k]
    return quat_to_dcm(q_nb)


# --- smooth profiles -------------------------------------------------------------------------------


def test_smooth_steps_derivatives_and_integral():
    p = SmoothSteps(1.0, starts=[2.0, 5.0], durations=[1.5, 2.0], deltas=[3.0, -4.0])
    t = np.linspace(0.0, 9.0, 901)
    x = p.derivs(t, 3)
    assert x[0][0] == 1.0 and x[0][-1] == pytest.approx(0.0) and np.all(x[0][t <= 2.0] == 1.0)
    h, off_knots = 1e-4, t + 0.0037
    for k in range(3):
        fd = (p.derivs(off_knots + h, k)[k] - p.derivs(off_knots - h, k)[k]) / (2 * h)
        np.testing.assert_allclose(fd, p.derivs(off_knots, k + 1)[k + 1], atol=1e-5 * 10**k)
    t_b = t[50::50]
    quad = [_gl_integral(lambda s: p.derivs(s)[0][:, None], 0.0, tb, n_sub=20, knots=p.knots)[0] for tb in t_b]
    np.testing.assert_allclose(p.integral(t_b), quad, rtol=0, atol=1e-13)
    assert p.integral(0.0) == 0.0 and p.integral(-1.0) == -1.0
    with pytest.raises(ValueError):
        SmoothSteps(0.0, starts=[0.0, 1.0], durations=[2.0, 1.0], deltas=[1.0, 1.0])


# --- exact truth -------------------------------------------------------------------------------------


def test_truth_derivatives_integrate_to_truth_differences(moving):
    """a_n, the Euler rates and the geodetic position rates integrate to the truth differences."""
    for t_a, t_b in [(0.0, 150.0), (100.0, 300.0)]:
        sa, sb = moving.state(t_a), moving.state(t_b)
        knots = moving.knots
        np.testing.assert_allclose(_gl_integral(lambda t: moving.state(t).a_n, t_a, t_b, knots=knots),
                                   sb.v_n[0] - sa.v_n[0], rtol=0, atol=1e-11)
        np.testing.assert_allclose(_gl_integral(lambda t: moving.state(t).euler_rate, t_a, t_b, knots=knots),
                                   sb.euler[0] - sa.euler[0], rtol=0, atol=1e-12)

        def llh_rate(t):
            st = moving.state(t)
            return st.v_n * earth.dr_to_dllh(st.llh[:, 0], st.llh[:, 2])

        dllh = _gl_integral(llh_rate, t_a, t_b, knots=knots) - (sb.llh[0] - sa.llh[0])
        assert np.all(np.abs(dllh * [earth.A, earth.A, 1.0]) < 1e-8)  # metres


def test_omega_nb_b_is_the_attitude_derivative(moving):
    t = np.linspace(1.0, 299.0, 300)
    h = 1e-5
    dC = (moving.state(t + h).C_nb - moving.state(t - h).C_nb) / (2 * h)
    st = moving.state(t)
    Omega = np.einsum("nji,njk->nik", st.C_nb, dC)  # C_bn dC_nb/dt = [omega_nb_b x]
    w = np.stack([Omega[:, 2, 1], Omega[:, 0, 2], Omega[:, 1, 0]], axis=-1)
    np.testing.assert_allclose(w, st.omega_nb_b, atol=1e-8)


def test_car_has_no_sideslip_and_covers_the_manoeuvres():
    car = make_trajectory("car", 1800.0, seed=0, start_llh=LLH0)
    st = car.state(np.arange(0.0, 1800.0, 0.1))
    v_b = np.einsum("nji,nj->ni", st.C_nb, st.v_n)
    speed = np.linalg.norm(st.v_n, axis=1)
    np.testing.assert_allclose(v_b[:, 0], speed, atol=1e-12)
    np.testing.assert_allclose(v_b[:, 1:], 0.0, atol=1e-12)
    yaw_rate, pitch = st.euler_rate[:, 2], st.euler[:, 1]
    assert yaw_rate.max() > 0.05 and yaw_rate.min() < -0.05  # right and left turns
    assert np.abs(pitch).max() > np.radians(1.0)  # hills
    assert np.any(speed[9000:] < 1e-9) and np.any(speed > 10.0)  # stops and cruising
    assert speed[0] == 0.0 and speed[-1] == 0.0
    assert np.all(speed < 25.0 + 1e-9) and np.all(np.abs(st.euler[:, 0]) < np.radians(2.0))


def test_multirotor_tilts_thrust_along_body_z_and_yaws_independently():
    uav = make_trajectory("multirotor", 900.0, seed=1, start_llh=LLH0)
    st = uav.state(np.arange(0.0, 900.0, 0.05))
    _, f_b = body_rates(st)
    a_h = np.linalg.norm(st.a_n[:, :2], axis=1)
    assert a_h.max() > 1.0 and np.abs(st.euler[:, :2]).max() > np.radians(5.0)
    assert np.abs(f_b[:, :2]).max() < 2e-3  # only the earth-rate terms, no horizontal thrust component
    moving = np.linalg.norm(st.v_n[:, :2], axis=1) > 1.0
    course = np.arctan2(st.v_n[moving, 1], st.v_n[moving, 0])
    assert np.abs(wrap_angle(course - st.euler[moving, 2])).max() > np.radians(90.0)
    assert abs(st.llh[-1, 2] - LLH0[2]) < 1e-6 and st.llh[:, 2].max() > LLH0[2] + 10.0  # lands at the start height


# --- ideal IMU ---------------------------------------------------------------------------------------


def test_at_rest_ideal_imu_senses_gravity_and_earth_rate():
    level = StaticTrajectory(LLH0, 10.0)
    st = level.state(np.linspace(0.0, 10.0, 11))
    omega_ib_b, f_b = body_rates(st)
    g = earth.gravity(LLH0[0], LLH0[2])
    np.testing.assert_allclose(f_b, np.tile([0.0, 0.0, -g], (11, 1)), rtol=0, atol=1e-9)
    np.testing.assert_allclose(omega_ib_b, np.tile(earth.omega_ie_n(LLH0[0]), (11, 1)), rtol=0, atol=1e-9)

    tilted = StaticTrajectory(LLH0, 10.0, euler=(0.3, -0.2, 2.0))
    st = tilted.state(np.linspace(0.0, 10.0, 11))
    omega_ib_b, f_b = body_rates(st)
    C_bn = st.C_nb[0].T
    np.testing.assert_allclose(omega_ib_b, np.tile(C_bn @ earth.omega_ie_n(LLH0[0]), (11, 1)), rtol=0, atol=1e-9)
    np.testing.assert_allclose(f_b, np.tile(C_bn @ [0.0, 0.0, -g], (11, 1)), rtol=0, atol=1e-9)
    dtheta, dvel = ideal_increments(tilted, np.arange(0, 101) * DT)
    np.testing.assert_allclose(dvel, np.tile(f_b[0] * DT, (100, 1)), rtol=1e-13)
    np.testing.assert_allclose(dtheta, np.tile(omega_ib_b[0] * DT, (100, 1)), rtol=1e-12)


def test_constant_yaw_rate_dtheta_reproduces_the_heading():
    yaw_rate = 0.3
    turntable = StaticTrajectory(LLH0, 60.0, euler=(0.0, 0.0, 0.2), yaw_rate=yaw_rate)
    edges = np.arange(0, 12001) * DT
    C_nb = _integrate_attitude(turntable, edges, dcm_to_quat(turntable.state(0.0).C_nb[0]))
    assert np.linalg.norm(dcm_to_rotvec(C_nb.T @ turntable.state(60.0).C_nb[0])) < 1e-9
    # The truth heading itself: yaw0 + rate * t.
    assert turntable.state(60.0).euler[0, 2] == pytest.approx(0.2 + yaw_rate * 60.0, abs=1e-12)


def test_dynamic_dtheta_reproduces_the_attitude(moving):
    edges = np.arange(0, 150 * 200 + 1) * DT
    C_nb = _integrate_attitude(moving, edges, dcm_to_quat(moving.state(0.0).C_nb[0]))
    assert np.linalg.norm(dcm_to_rotvec(C_nb.T @ moving.state(150.0).C_nb[0])) < 1e-8


def test_specific_force_satisfies_the_navigation_equation(moving):
    st = moving.state(np.linspace(0.0, 300.0, 3001))
    _, f_b = body_rates(st)
    lat, h = st.llh[:, 0], st.llh[:, 2]
    w_ie, w_en = earth.omega_ie_n(lat), earth.omega_en_n(lat, h, st.v_n)
    g_n = np.zeros_like(f_b)
    g_n[:, 2] = earth.gravity(lat, h)
    v_dot = np.einsum("nij,nj->ni", st.C_nb, f_b) - np.cross(2 * w_ie + w_en, st.v_n) + g_n
    np.testing.assert_allclose(v_dot, st.a_n, rtol=0, atol=1e-12)


def test_dvel_with_a_simple_mechanization_reproduces_the_velocity(moving):
    """Velocity update from dvel (rotation + sculling) with the truth attitude: drift only from the
    algorithm's O(dt^2) terms, far below the m/s a wrong frame, sign or gravity would give."""
    edges = np.arange(0, 300 * 200 + 1) * DT
    dtheta, dvel = ideal_increments(moving, edges)
    s0, sm = moving.state(edges[:-1]), moving.state(0.5 * (edges[1:] + edges[:-1]))
    lat, h = sm.llh[:, 0], sm.llh[:, 2]
    w_ie, w_en = earth.omega_ie_n(lat), earth.omega_en_n(lat, h, sm.v_n)
    prev_th, prev_dv = np.roll(dtheta, 1, axis=0), np.roll(dvel, 1, axis=0)
    prev_th[0] = prev_dv[0] = 0.0
    dv_b = dvel + 0.5 * np.cross(dtheta, dvel) + (np.cross(prev_th, dvel) + np.cross(prev_dv, dtheta)) / 12.0
    dv_n = np.einsum("nij,nj->ni", s0.C_nb, dv_b)
    dv_n -= 0.5 * np.cross((w_ie + w_en) * DT, dv_n)
    dv_n -= np.cross(2 * w_ie + w_en, sm.v_n) * DT
    dv_n[:, 2] += earth.gravity(lat, h) * DT
    v_n = s0.v_n[0] + np.cumsum(dv_n, axis=0)
    assert np.abs(v_n - moving.state(edges[1:]).v_n).max() < 1e-4


def test_increments_match_a_brute_force_quadrature(moving):
    """Gauss-Legendre pieces split at the knots == composite Simpson with 256 sub-steps per interval."""
    knot = moving.knots[(moving.knots > 20.0)][0]
    edges = np.round(knot / DT) * DT + np.arange(-50, 51) * DT  # 100 intervals around a knot
    dtheta, dvel = ideal_increments(moving, edges)
    n = 256
    fine = np.linspace(edges[0], edges[-1], 100 * n + 1)
    rates = np.concatenate(body_rates(moving.state(fine)), axis=1)
    simpson = (rates[0:-1:2] + 4 * rates[1::2] + rates[2::2]) * (edges[-1] - edges[0]) / (100 * n) / 3
    ref = simpson.reshape(100, n // 2, 6).sum(axis=1)
    np.testing.assert_allclose(dtheta, ref[:, :3], rtol=0, atol=1e-14)
    np.testing.assert_allclose(dvel, ref[:, 3:], rtol=0, atol=1e-12)
    d3, d6 = ideal_increments(moving, edges, n_nodes=3), ideal_increments(moving, edges, n_nodes=6)
    np.testing.assert_allclose(d3[0], d6[0], rtol=0, atol=1e-16)


# --- IMU errors ----------------------------------------------------------------------------------------


def test_gauss_markov_has_the_stationary_std_and_correlation_time():
    sigma, tau, dt = 2.0, 1.0, 0.01
    b = gauss_markov(400_000, dt, sigma, tau, np.random.default_rng(7), dim=2)
    assert np.all(np.abs(b.std(axis=0) / sigma - 1.0) < 0.1)
    lag = int(tau / dt)
    rho = np.mean(b[lag:] * b[:-lag], axis=0) / b.var(axis=0)
    assert np.all(np.abs(rho - np.exp(-1.0)) < 0.05)
    starts = gauss_markov(2, dt, sigma, tau, np.random.default_rng(8), dim=20_000)[0]  # turn-on values
    assert abs(starts.std() / sigma - 1.0) < 0.1


@pytest.mark.parametrize("n, dt, sigma, tau", [(20_000, 0.005, 1e-4, 3600.0), (500, 0.01, 2.0, 0.05),
                                               (50, 0.005, 1e-3, np.inf), (1, 1.0, 1.0, 1.0)])
def test_gauss_markov_is_scipy_lfilter_bit_for_bit(n, dt, sigma, tau):
    """The recursion in Python floats (no scipy.signal import) gives scipy.signal.lfilter's floats: the simulated
    datasets, and every replay of them, stay the same."""
    from scipy.signal import lfilter

    got = gauss_markov(n, dt, sigma, tau, np.random.default_rng(5))
    rng = np.random.default_rng(5)
    phi = np.exp(-dt / tau)
    e = sigma * np.sqrt(-np.expm1(-2.0 * dt / tau)) * rng.standard_normal((n, 3))
    e[0] = sigma * rng.standard_normal(3)
    want = lfilter([1.0], [1.0, -phi], e, axis=0)
    assert got.shape == want.shape and got.flags.c_contiguous and np.array_equal(got, want)


def test_imu_white_noise_and_bias_series():
    traj = StaticTrajectory(LLH0, 100.0, euler=(0.1, 0.0, 1.0))
    noise = IMU_GRADES["mems"].noise()
    t_ns = np.arange(20_001, dtype=np.int64) * int(DT * NS)
    imu, err = simulate_imu(traj, t_ns, 0, noise, np.random.default_rng(3))
    dtheta, dvel = ideal_increments(traj, np.concatenate([[-DT], t_ns / NS]))
    gyro_white = imu.dtheta - dtheta - err.gyro_bias * DT
    accel_white = imu.dvel - dvel - err.accel_bias * DT
    assert np.all(np.abs(gyro_white.std(axis=0) / (noise.arw * np.sqrt(DT)) - 1.0) < 0.1)
    assert np.all(np.abs(accel_white.std(axis=0) / (noise.vrw * np.sqrt(DT)) - 1.0) < 0.1)
    assert err.gyro_bias.shape == (len(t_ns), 3) and np.all(err.gyro_bias.std(axis=0) > 0.0)
    with pytest.raises(ValueError):
        simulate_imu(traj, t_ns[[0, 1, 3]], 0, noise, np.random.default_rng(3))


# --- GNSS ----------------------------------------------------------------------------------------------


def test_antenna_position_and_velocity_follow_the_lever_arm(moving):
    lever_arm_b = np.array([0.5, 0.2, -1.0])
    t = np.linspace(10.0, 290.0, 57)
    llh_ant, v_ant = antenna_truth(moving, t, lever_arm_b)
    st = moving.state(t)
    for k in range(len(t)):
        np.testing.assert_allclose(earth.llh_to_ned(llh_ant[k], st.llh[k]), st.C_nb[k] @ lever_arm_b, atol=1e-6)
    h = 1e-3
    r_p, r_m = antenna_truth(moving, t + h, lever_arm_b)[0], antenna_truth(moving, t - h, lever_arm_b)[0]
    v_fd = np.array([earth.llh_to_ned(r_p[k], r_m[k]) / (2 * h) for k in range(len(t))])
    np.testing.assert_allclose(v_fd, v_ant, atol=1e-5)


def test_gnss_noise_has_the_configured_std(moving):
    std_ned, vel_std = np.array([0.5, 0.8, 1.5]), 0.05
    t_ns = np.arange(0, 300 * 10 + 1, dtype=np.int64) * (NS // 10)
    gnss = simulate_gnss(moving, t_ns, 0, (0.5, 0.2, -1.0), std_ned, vel_std, np.random.default_rng(4),
                         FixType.RTK_FIXED, 17)
    llh_ant, v_ant = antenna_truth(moving, t_ns / NS, (0.5, 0.2, -1.0))
    err_ned = (gnss.llh - llh_ant) / earth.dr_to_dllh(llh_ant[:, 0], llh_ant[:, 2])
    assert np.all(np.abs(err_ned.std(axis=0) / std_ned - 1.0) < 0.1)
    assert np.all(np.abs((gnss.v_n - v_ant).std(axis=0) / vel_std - 1.0) < 0.1)
    np.testing.assert_array_equal(gnss.std_ned, np.tile(std_ned, (len(t_ns), 1)))
    assert np.all(gnss.std_v_n == vel_std) and np.all(gnss.fix == FixType.RTK_FIXED) and np.all(gnss.num_sats == 17)


# --- datasets ------------------------------------------------------------------------------------------


def test_dataset_layout_and_configuration():
    ds = make_dataset("car", duration_s=120.0, gnss_rate_hz=5.0, seed=2)
    t0 = 356400 * NS
    assert ds.imu.t_ns[0] == t0 and np.all(np.diff(ds.imu.t_ns) == 5_000_000) and len(ds.imu) == 24001
    assert ds.gnss.t_ns[0] == t0 and ds.gnss.t_ns[-1] == ds.imu.t_ns[-1]
    assert np.all(ds.gnss.t_ns % (NS // 5) == 0) and len(ds.gnss) == 601
    assert np.all(ds.gnss.fix == FixType.SINGLE) and ds.gnss.v_n is not None
    np.testing.assert_array_equal(ds.truth.t_ns, ds.imu.t_ns)
    assert ds.truth.source == "simulator (exact)" and np.all(np.abs(ds.truth.euler[:, 2]) <= np.pi)
    assert ds.config.imu_noise == IMU_GRADES["mems"].noise()
    np.testing.assert_array_equal(ds.config.lever_arm_b, [0.5, 0.2, -1.0])
    assert (ds.config.start_t_ns, ds.config.end_t_ns) == (ds.imu.t_ns[0], ds.imu.t_ns[-1])
    # Initial state: truth plus the recorded error, which is within 5 sigma.
    ini, err = ds.initial, ds.notes["initial_error"]
    np.testing.assert_allclose(earth.llh_to_ned(ini.llh, ds.truth.llh[0]), err["pos_ned_m"], atol=1e-6)
    np.testing.assert_allclose(ini.v_n - ds.truth.v_n[0], err["v_n_mps"], atol=1e-12)
    np.testing.assert_allclose(wrap_angle(ini.euler - ds.truth.euler[0]), err["euler_rad"], atol=1e-12)
    assert np.all(np.abs(err["euler_rad"]) < 5 * ini.std_euler) and np.any(np.abs(err["euler_rad"]) > 0)
    np.testing.assert_allclose(ini.std_gyro_bias, ds.config.imu_noise.gyro_bias_std)
    biases = true_biases(ds)
    assert biases.gyro_bias.shape == biases.accel_bias.shape == (len(ds.imu), 3)
    exact = make_dataset("static", duration_s=10.0, perturb_initial=False, gnss_std_ned=(0.02, 0.02, 0.05))
    np.testing.assert_array_equal(exact.initial.llh, exact.truth.llh[0])
    assert np.all(exact.gnss.fix == FixType.RTK_FIXED)


def test_datasets_reproduce_with_the_same_seed_and_differ_with_another():
    a = make_dataset("multirotor", duration_s=60.0, seed=5)
    b = make_dataset("multirotor", duration_s=60.0, seed=5)
    c = make_dataset("multirotor", duration_s=60.0, seed=6)
    for x, y in [(a.imu.dtheta, b.imu.dtheta), (a.imu.dvel, b.imu.dvel), (a.gnss.llh, b.gnss.llh),
                 (a.truth.llh, b.truth.llh), (a.initial.euler, b.initial.euler)]:
        np.testing.assert_array_equal(x, y)
    assert not np.allclose(a.imu.dvel, c.imu.dvel) and not np.allclose(a.truth.euler, c.truth.euler)
    # The IMU stream does not depend on the GNSS settings.
    d = make_dataset("multirotor", duration_s=60.0, seed=5, gnss_rate_hz=10.0, gnss_std_ned=(1.0, 1.0, 2.0))
    np.testing.assert_array_equal(a.imu.dvel, d.imu.dvel)


def test_ideal_grade_gives_noise_free_increments():
    ds = make_dataset("car", duration_s=30.0, imu_grade="ideal", seed=1)
    traj = ds.notes["trajectory"]
    t_s = (ds.imu.t_ns - ds.imu.t_ns[0]) / NS
    dtheta, dvel = ideal_increments(traj, np.concatenate([[t_s[0] - DT], t_s]))
    np.testing.assert_array_equal(ds.imu.dtheta, dtheta)
    np.testing.assert_array_equal(ds.imu.dvel, dvel)
    assert ds.config.imu_noise == ImuNoise(0.0, 0.0, 0.0, 0.0, 3600.0, 3600.0)
    with pytest.raises(ValueError):
        make_dataset("car", duration_s=10.0, imu_grade="unobtainium")


# --- the cache of generated series (zennav.sim.cache) ---------------------------------------------------


@pytest.fixture
def sim_cache(tmp_path, monkeypatch):
    """The simulator's cache in tmp_path, used for datasets of any size, its counters from zero: the folder."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.delenv("ZENNAV_CACHE", raising=False)
    monkeypatch.setattr(cache, "MIN_SAMPLES", 0)
    monkeypatch.setattr(cache, "STATS", Counter())
    return tmp_path / "zennav" / "sim"


def _assert_same_series(a, b):
    """The series the cache provides, as the datasets a and b expose them, bit for bit (and their summaries)."""
    ea, eb = true_biases(a), true_biases(b)
    for x, y in [(a.imu.dtheta, b.imu.dtheta), (a.imu.dvel, b.imu.dvel), (ea.gyro_bias, eb.gyro_bias),
                 (ea.accel_bias, eb.accel_bias), (a.notes["gyro_scale"], b.notes["gyro_scale"]),
                 (a.notes["accel_scale"], b.notes["accel_scale"]), (a.truth.llh, b.truth.llh),
                 (a.truth.v_n, b.truth.v_n), (a.truth.euler, b.truth.euler), (a.initial.llh, b.initial.llh),
                 (a.initial.v_n, b.initial.v_n), (a.gnss.llh, b.gnss.llh)]:
        assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes()
    assert a.notes["gyro_bias_std_deg_h"] == b.notes["gyro_bias_std_deg_h"]


def test_cached_series_are_the_generated_ones_bit_for_bit(sim_cache, monkeypatch):
    kw = dict(duration_s=20.0, seed=3, scale_ppm=300.0)
    monkeypatch.setenv("ZENNAV_CACHE", "0")
    fresh = make_dataset("car", **kw)
    assert not sim_cache.exists() and not cache.STATS  # off: neither read nor written
    monkeypatch.delenv("ZENNAV_CACHE")
    stored = make_dataset("car", **kw)
    read = make_dataset("car", **kw)
    assert cache.STATS == Counter(miss=1, stored=1, hit=1) and len(list(sim_cache.glob("*.npz"))) == 1
    _assert_same_series(fresh, stored)
    _assert_same_series(fresh, read)
    assert np.any(read.notes["gyro_scale"] != 0.0)
    other = make_dataset("car", **{**kw, "seed": 4})  # another parameter: another key, another file
    assert cache.STATS["miss"] == 2 and len(list(sim_cache.glob("*.npz"))) == 2
    assert not np.allclose(other.imu.dvel, fresh.imu.dvel)


def test_the_key_holds_the_parameters_and_the_sources(monkeypatch):
    text = cache.key_text({"seed": 1, "x": np.arange(3.0)})
    assert text != cache.key_text({"seed": 1, "x": np.arange(3)})  # the dtype counts
    assert text != cache.key_text({"seed": 2, "x": np.arange(3.0)})
    monkeypatch.setattr(cache, "_SOURCES", cache._SOURCES[1:])
    assert text != cache.key_text({"seed": 1, "x": np.arange(3.0)})
    with pytest.raises(TypeError):
        cache.key_text({"seed": object()})  # no key from a repr that may name a memory address


def test_an_unreadable_or_unwritable_cache_is_logged_and_the_series_generated(sim_cache, monkeypatch, caplog):
    kw = dict(duration_s=10.0, seed=1)
    first = make_dataset("static", **kw)
    (path,) = sim_cache.glob("*.npz")
    path.write_bytes(path.read_bytes()[:1000])  # truncated
    with caplog.at_level(logging.WARNING, logger="zennav.sim"):
        _assert_same_series(first, make_dataset("static", **kw))
    assert cache.STATS["unreadable"] == 1 and "unreadable" in caplog.text
    np.savez(path, dtheta=np.zeros((3, 3)), __key__=np.array("another key"))  # not this key's
    _assert_same_series(first, make_dataset("static", **kw))
    assert cache.STATS["unreadable"] == 2 and cache.STATS["stored"] == 3
    _assert_same_series(first, make_dataset("static", **kw))  # rewritten: read
    assert cache.STATS["hit"] == 1
    blocked = sim_cache.parent.parent / "file"
    blocked.write_text("")
    monkeypatch.setenv("XDG_CACHE_HOME", str(blocked))  # its folder cannot be made
    _assert_same_series(first, make_dataset("static", **kw))
    assert cache.STATS["unwritable"] == 1


def test_the_cache_stays_under_its_bound(sim_cache, monkeypatch):
    make_dataset("static", duration_s=10.0, seed=1)
    (old,) = sim_cache.glob("*.npz")
    os.utime(old, (1e9, 1e9))  # long unused
    stale = sim_cache / ".crashed.tmp"
    stale.write_bytes(b"x")
    os.utime(stale, (1e9, 1e9))
    monkeypatch.setattr(cache, "MAX_BYTES", int(1.5 * old.stat().st_size))
    make_dataset("static", duration_s=10.0, seed=2)
    (new,) = sim_cache.glob("*.npz")
    assert new != old and cache.STATS["evicted"] == 1 and not stale.exists()
