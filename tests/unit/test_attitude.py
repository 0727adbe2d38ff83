"""Seed 000 attitude filter: bias convergence, rejection, known rotations, earth rate, split runs."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from zennav.attitude.complementary import AdaptiveComplementaryFilter, ComplementaryConfig
from zennav.nav.earth import G0, omega_ie_n
from zennav.nav.rotation import euler_to_quat, quat_multiply, quat_to_dcm, quat_to_euler, rotvec_to_quat

REPO = Path(__file__).resolve().parents[2]
DEG = math.pi / 180.0
G_N = np.array([0.0, 0.0, G0])  # gravity in NED [m/s^2]
ZERO = (0.0, 0.0, 0.0)


def tilt_error(q_est, q_true) -> float:
    """Angle between estimated and true down axes [rad]: the inclination error."""
    d_est, d_true = quat_to_dcm(q_est)[2], quat_to_dcm(q_true)[2]
    return math.acos(min(1.0, float(d_est @ d_true)))


def static_imu(q_nb, bias_b, n, rng, gyro_noise=0.0, acc_noise=0.0):
    """Gyro [rad/s] and specific force [m/s^2] of a body at rest with attitude q_nb, no earth rate."""
    f_b = quat_to_dcm(q_nb).T @ (-G_N)
    omega = np.tile(bias_b, (n, 1)) + gyro_noise * rng.standard_normal((n, 3))
    f = np.tile(f_b, (n, 1)) + acc_noise * rng.standard_normal((n, 3))
    return omega, f


def test_bias_converges_at_rest():
    """All three axes (the rest update sees the vertical one): within 0.01 deg/s after 30 s at 100 Hz."""
    rng = np.random.default_rng(1)
    bias = np.array([0.5, -0.3, 0.4]) * DEG
    q_nb = euler_to_quat((10 * DEG, -5 * DEG, 0.0))
    omega, f = static_imu(q_nb, bias, 3000, rng, gyro_noise=0.05 * DEG, acc_noise=0.02)
    out = AdaptiveComplementaryFilter().batch(omega, f, dt=0.01)
    assert np.all(np.abs(out.bias_b[-1] - bias) < 0.01 * DEG)
    assert tilt_error(out.q_nb[-1], q_nb) < 0.1 * DEG


def test_integral_alone_converges_to_horizontal_bias():
    """Without the rest update the PI integral finds the bias across gravity (not along it):
    within 0.005 deg/s after 60 s with tau_acc = 1 s, tau_bias = 5 s."""
    rng = np.random.default_rng(2)
    bias = np.array([0.5, -0.3, 0.4]) * DEG
    q_nb = euler_to_quat((10 * DEG, -5 * DEG, 0.0))
    omega, f = static_imu(q_nb, bias, 6000, rng, gyro_noise=0.05 * DEG)
    cfg = ComplementaryConfig(tau_acc_s=1.0, tau_bias_s=5.0, acc_lowpass_s=0.5, rest_gyro_dps=0.0)
    out = AdaptiveComplementaryFilter(cfg).batch(omega, f, dt=0.01)
    down_b = quat_to_dcm(q_nb)[2]  # C_bn [0, 0, 1]
    err = out.bias_b[-1] - bias
    err_across = err - (err @ down_b) * down_b
    assert np.linalg.norm(err_across) < 0.005 * DEG
    # Along gravity the integral learns nothing (its estimate stays near 0, far from the bias there).
    assert abs(out.bias_b[-1] @ down_b) < 0.05 * abs(bias @ down_b)


def test_rejection_engages_under_sustained_acceleration():
    """10 s at rest, then 20 s of 3 m/s^2 forward: the weight drops below 0.05 and tilt stays within
    0.3 deg; the same filter without rejection tilts by more than 5 deg."""
    rng = np.random.default_rng(3)
    dt, n_rest, n_acc = 0.01, 1000, 2000
    q_nb = np.array([1.0, 0.0, 0.0, 0.0])
    omega, f = static_imu(q_nb, np.zeros(3), n_rest + n_acc, rng, gyro_noise=0.02 * DEG, acc_noise=0.02)
    f[n_rest:, 0] += 3.0  # specific force of a level body accelerating north at 3 m/s^2
    gated = ComplementaryConfig(reject_start_mps2=0.1, reject_full_mps2=0.3, reject_hold_s=0.2)
    out = AdaptiveComplementaryFilter(gated).batch(omega, f, dt=dt)
    assert np.all(out.weight[:n_rest] == 1.0)
    assert np.all(out.weight[n_rest + 100 :] < 0.05)
    assert max(tilt_error(q, q_nb) for q in out.q_nb) < 0.3 * DEG
    ungated = ComplementaryConfig(reject_start_mps2=100.0, reject_full_mps2=200.0)
    out = AdaptiveComplementaryFilter(ungated).batch(omega, f, dt=dt)
    assert np.all(out.weight == 1.0)
    assert tilt_error(out.q_nb[-1], q_nb) > 5 * DEG


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_constant_rate_reproduces_exact_quaternion(axis):
    """30 deg/s about one body axis for 10 s at 200 Hz from a tilted start: the estimate stays within
    2e-5 rad (total angle) of q0 * exp(omega t / 2); the first-order step alone errs 3e-6 rad here."""
    dt, n = 0.005, 2000
    rate = np.zeros(3)
    rate[axis] = 30 * DEG
    q0 = euler_to_quat((20 * DEG, -10 * DEG, 0.0))
    q_true = [quat_multiply(q0, rotvec_to_quat(rate * dt * (k + 1))) for k in range(n)]
    f = np.array([quat_to_dcm(q).T @ (-G_N) for q in q_true])
    flt = AdaptiveComplementaryFilter()
    flt.level(quat_to_dcm(q0).T @ (-G_N))
    out = flt.batch(np.tile(rate, (n, 1)), f, dt=dt)
    for k in (n // 2, n - 1):
        d = quat_multiply(np.array([1.0, -1.0, -1.0, -1.0]) * q_true[k], out.q_nb[k])
        assert 2.0 * math.atan2(np.linalg.norm(d[1:]), abs(d[0])) < 2e-5


def test_earth_rate_is_removed_when_supplied():
    """At rest at 45 deg latitude the gyro sees earth rate: with omega_in_n supplied the heading holds
    (< 1e-4 rad after 600 s); without it (rest update off) the heading drifts by -Omega sin(lat) t."""
    lat, dt, n = 45 * DEG, 0.01, 60000
    w_ie_n = omega_ie_n(lat)
    q_nb = euler_to_quat((0.0, 0.0, 0.3))
    omega = np.tile(quat_to_dcm(q_nb).T @ w_ie_n, (n, 1))
    f = np.tile(quat_to_dcm(q_nb).T @ (-G_N), (n, 1))
    cfg = ComplementaryConfig(rest_gyro_dps=0.0)
    filters = [AdaptiveComplementaryFilter(cfg) for _ in range(2)]
    for flt in filters:
        flt.set_state(replace(flt.get_state(), q_nb=q_nb))  # start at the true heading
    out = filters[0].batch(omega, f, dt=dt, omega_in_n=w_ie_n)
    assert abs(quat_to_euler(out.q_nb[-1])[2] - 0.3) < 1e-4
    yaw = quat_to_euler(filters[1].batch(omega, f, dt=dt).q_nb[-1])[2]
    expected = 0.3 + w_ie_n[2] * n * dt  # yaw rate = down component of omega_ie_n = -Omega sin(lat)
    assert abs(yaw - expected) < 0.02 * abs(expected - 0.3)


def manoeuvre(rng, n=4000, dt=0.005):
    """Noisy IMU record with rotation, translation spikes and rest: gyro [rad/s], f [m/s^2]."""
    t = np.arange(n) * dt
    omega = 0.5 * np.column_stack([np.sin(1.3 * t), np.cos(0.7 * t), np.sin(2.1 * t + 1.0)])
    omega[: n // 4] = 0.0
    omega += 0.003 + 0.002 * rng.standard_normal((n, 3))  # at rest (first 5 s) below rest_gyro_dps
    f = np.tile([0.3, -0.2, -G0], (n, 1)) + 0.05 * rng.standard_normal((n, 3))
    f[n // 2 : n // 2 + 200] += [15.0, -8.0, 4.0]
    return t, omega, f


@pytest.mark.parametrize("mode", ["dt", "t"])
def test_split_run_equals_full_run(mode):
    """Batch over all samples == batch, get_state, new filter, set_state, batch (bit for bit), with
    Earth/transport rate supplied; the step API gives the same bits."""
    rng = np.random.default_rng(4)
    t, omega, f = manoeuvre(rng)
    w_in = np.tile([1e-5, -2e-5, 3e-5], (len(t), 1))
    kw = (lambda s: {"dt": 0.005}) if mode == "dt" else (lambda s: {"t": t[s]})
    ref = AdaptiveComplementaryFilter()
    ref.level(f[:100])
    full = ref.batch(omega, f, omega_in_n=w_in, **kw(slice(None)))
    if mode == "dt":  # batch levels itself from the first level_time_s = 0.5 s = 100 samples
        auto = AdaptiveComplementaryFilter().batch(omega, f, omega_in_n=w_in, dt=0.005)
        np.testing.assert_array_equal(auto.q_nb, full.q_nb)
    for cut in (1, 500, 1234, 2999):
        a = AdaptiveComplementaryFilter()
        a.level(f[:100])
        first = a.batch(omega[:cut], f[:cut], omega_in_n=w_in[:cut], **kw(slice(None, cut)))
        b = AdaptiveComplementaryFilter()
        b.set_state(a.get_state())
        second = b.batch(omega[cut:], f[cut:], omega_in_n=w_in[cut:], **kw(slice(cut, None)))
        for name in ("q_nb", "bias_b", "weight"):
            joined = np.concatenate([getattr(first, name), getattr(second, name)])
            np.testing.assert_array_equal(joined, getattr(full, name))
    stepper = AdaptiveComplementaryFilter()
    stepper.level(f[:100])
    dts = np.full(len(t), 0.005) if mode == "dt" else np.diff(t, prepend=t[0])  # t: first interval 0
    for k in range(len(t)):
        state = stepper.step(dts[k], omega[k], f[k], w_in[k])
    np.testing.assert_array_equal(state.q_nb, full.q_nb[-1])
    np.testing.assert_array_equal(state.bias_b, full.bias_b[-1])
    assert state.weight == full.weight[-1]


def test_rejection_weight_drops_on_spikes_and_recovers():
    """A 1 s disturbance of ~8.5 m/s^2 in |f| drives p(a) to 0 (thresholds 1 and 6 m/s^2, hold 0.5 s);
    p(a) is back to 1 within 2 s after it, and always in [0, 1]."""
    _, omega, f = manoeuvre(np.random.default_rng(5))
    cfg = ComplementaryConfig(reject_start_mps2=1.0, reject_full_mps2=6.0, reject_hold_s=0.5)
    w = AdaptiveComplementaryFilter(cfg).batch(omega, f, dt=0.005).weight
    assert np.all(w[:2000] == 1.0)
    assert w[2000:2200].min() == 0.0
    assert np.all(w[2200 + 400 :] == 1.0)
    assert np.all((w >= 0.0) & (w <= 1.0))


def test_parameter_file_and_validation():
    """deploy/attitude.yaml loads into the config; unknown keys and inconsistent gains are refused."""
    mapping = yaml.safe_load((REPO / "deploy" / "attitude.yaml").read_text())["attitude"]
    cfg = ComplementaryConfig.from_mapping(mapping)
    k_p, k_i = cfg.gains()
    assert k_p == pytest.approx(1.0 / mapping["tau_acc_s"])
    assert k_i == pytest.approx(1.0 / (mapping["tau_acc_s"] * mapping["tau_bias_s"]))
    with pytest.raises(ValueError):
        ComplementaryConfig.from_mapping({**mapping, "k_p": 1.0})
    with pytest.raises(ValueError):
        ComplementaryConfig(reject_start_mps2=2.0, reject_full_mps2=1.0)
    with pytest.raises(ValueError):
        ComplementaryConfig(tau_acc_s=0.0)
    with pytest.raises(ValueError):
        AdaptiveComplementaryFilter().batch(np.zeros((3, 3)), np.zeros((3, 3)))


def drive(rng, dt=0.01):
    """Level vehicle: 10 s at rest, 30 s accelerating forward at 1.5 m/s^2, 30 s turning right at 0.05 rad/s at
    constant speed (2.25 m/s^2 centripetal): t [s], gyro [rad/s], specific force [m/s^2] (both noisy) and the true
    forward speed [m/s]; roll and pitch are 0 throughout."""
    t = np.arange(7000) * dt
    accel = np.where((t >= 10.0) & (t < 40.0), 1.5, 0.0)
    speed = np.concatenate([[0.0], np.cumsum(accel[:-1]) * dt])
    yaw_rate = np.where(t >= 40.0, 0.05, 0.0)
    omega = np.column_stack([np.zeros_like(t), np.zeros_like(t), yaw_rate]) + 0.002 * rng.standard_normal((7000, 3))
    f = np.column_stack([accel, yaw_rate * speed, np.full_like(t, -G0)]) + 0.02 * rng.standard_normal((7000, 3))
    return t, omega, f, speed


def test_acceleration_compensation_holds_the_tilt_the_filter_alone_loses():
    """A sustained forward acceleration and then a turn, below the rejection's reach (||f| - g| <= 0.26 m/s^2):
    the filter alone tilts by more than 5 deg; with a_b, v_b from a 10 Hz velocity source (the forward speed,
    zennav.attitude.acceleration) the tilt stays within 0.5 deg (0.28 here: the 0.1 s differencing lag at the
    acceleration's steps, the speed noise), and the reference is applied to every sample
    once it has two velocity samples."""
    from zennav.attitude.acceleration import AccelerationReference

    rng = np.random.default_rng(6)
    t, omega, f, speed = drive(rng)
    level = np.array([1.0, 0.0, 0.0, 0.0])
    alone = AdaptiveComplementaryFilter().batch(omega, f, dt=0.01)
    assert max(tilt_error(q, level) for q in alone.q_nb) > 5 * DEG
    ref = AccelerationReference(min_span_s=0.1, max_age_s=1.5)
    flt = AdaptiveComplementaryFilter()
    errs, bias = [], np.zeros(3)
    for k in range(len(t)):
        t_ns = int(round(t[k] * 1e9))
        if k % 10 == 0:
            ref.add(t_ns, (speed[k] + 0.02 * rng.standard_normal(), 0.0, 0.0))
        r = ref.at(t_ns, omega[k] - bias)
        s = flt.step(0.01, omega[k], f[k], a_b=r[0] if r else (0.0, 0.0, 0.0), v_b=r[1] if r else (0.0, 0.0, 0.0))
        bias = s.bias_b
        errs.append(tilt_error(s.q_nb, level))
    assert max(errs) < 0.5 * DEG
    assert ref.counts["applied"] == len(t) - 10 and ref.counts["stale"] == 0


def test_acceleration_reference_levelling_window_takes_the_mean_acceleration():
    """Over a held levelling window dv_b/dt is the velocity change across it over its span (a velocity step at its
    end, as an ins velocity at a GNSS update, counts once over the window, where the newest 0.1 s difference
    would read it as 2 m/s^2 more), v_b the newest sample at each time; too short a span falls back to ``at``."""
    from zennav.attitude.acceleration import AccelerationReference

    s = 1_000_000_000
    ref = AccelerationReference(min_span_s=0.1, max_age_s=1.0)
    times = [k * s // 100 for k in range(51)]  # 0.5 s at 100 Hz: 1 m/s^2 forward, a 0.2 m/s step at the end
    for t in times:
        ref.add(t, (5.0 + t / s + (0.2 if t == times[-1] else 0.0), 0.0, 0.0))
    out = ref.window(times, [(0.0, 0.0, 0.1)] * len(times))
    a_b, v_b = out[-1]
    assert a_b == pytest.approx((1.0 + 0.2 / 0.5, 0.1 * 5.7, 0.0)) and v_b == pytest.approx((5.7, 0.0, 0.0))
    assert out[10][1] == pytest.approx((5.1, 0.0, 0.0)) and ref.counts["applied"] == len(times)
    ref = AccelerationReference(min_span_s=0.1, max_age_s=1.0)
    for t in times:
        ref.add(t, (5.0 + t / s + (0.2 if t == times[-1] else 0.0), 0.0, 0.0))
    assert ref.at(times[-1], ZERO)[0][0] == pytest.approx(1.0 + 0.2 / 0.1)  # the newest difference, for contrast
    ref = AccelerationReference(min_span_s=0.2, max_age_s=1.0)
    ref.add(0, (5.0, 0.0, 0.0))
    ref.add(s // 10, (5.1, 0.0, 0.0))
    assert ref.window([0, s // 10], [ZERO, ZERO]) == [None, None] and ref.counts["none"] == 2


def test_acceleration_reference_differences_holds_and_rejects():
    """dv_b/dt over the newest span >= min_span, extrapolated with the jerk between differences >= min_span apart,
    omega x v_b with v_b extrapolated; a sample waits until the IMU reaches its time; stale estimates, gaps,
    non-finite and non-increasing samples are counted, never used."""
    from zennav.attitude.acceleration import AccelerationReference, body_velocity_of_solution, body_velocity_of_speed

    s = 1_000_000_000
    ref = AccelerationReference(min_span_s=0.2, max_age_s=1.0)
    assert ref.at(0, ZERO) is None and ref.counts["none"] == 1
    for k in range(4):  # 10 Hz, 2 m/s^2 forward
        assert ref.add(k * s // 10, (10.0 + 0.2 * k, 1.0, 0.0)) == ""
    assert ref.at(s // 20, ZERO) is None  # only the first sample reached: nothing to difference yet
    a_b, v_b = ref.at(3 * s // 10, (0.0, 0.0, 0.5))  # samples 0..3 reached: (v3 - v1) / 0.2 s
    assert v_b == pytest.approx((10.6, 1.0, 0.0))
    assert a_b == pytest.approx((2.0 - 0.5 * 1.0, 0.5 * 10.6, 0.0))
    a_b, v_b = ref.at(8 * s // 10, ZERO)  # held and extrapolated 0.5 s on
    assert a_b == pytest.approx((2.0, 0.0, 0.0)) and v_b == pytest.approx((11.6, 1.0, 0.0))
    assert ref.at(13 * s // 10 + 1, ZERO) is None and ref.counts["stale"] == 1  # 1 s after the newest sample
    assert ref.add(0, (1.0, 0.0, 0.0)) == "not_increasing"
    assert ref.add(5 * s, (float("nan"), 0.0, 0.0)) == "not_finite"
    assert ref.add(5 * s, (20.0, 0.0, 0.0)) == ""  # 4.7 s after the last: a gap, no difference across it
    assert ref.at(5 * s, ZERO) is None and ref.counts["gap"] == 1
    assert ref.counts["velocity"] == 5 and ref.counts["applied"] == 2
    # constant jerk (1 m/s^3 forward from rest): the differences are exact at their midpoints, the jerk from two of
    # them min_span apart, so 0.3 s after the last sample a = 1.3 m/s^2 and v = 0.845 m/s exactly
    ref = AccelerationReference(min_span_s=0.2, max_age_s=1.0, jerk=True)
    for k in range(11):
        ref.add(k * s // 10, (0.5 * (k / 10) ** 2, 0.0, 0.0))
    a_b, v_b = ref.at(13 * s // 10, ZERO)
    assert a_b == pytest.approx((1.3, 0.0, 0.0), abs=1e-9) and v_b == pytest.approx((0.845, 0.0, 0.0), abs=1e-9)
    # sources: v_b = C_bn v_n with the ins attitude (heading 90 deg: north velocity is to the left), or speed
    q_east = euler_to_quat((0.0, 0.0, 90 * DEG))
    assert body_velocity_of_solution(q_east, (3.0, 0.0, 0.0)) == pytest.approx((0.0, -3.0, 0.0), abs=1e-12)
    assert body_velocity_of_speed((3.0, -4.0, 0.0)) == (5.0, 0.0, 0.0)
    with pytest.raises(ValueError):
        AccelerationReference(min_span_s=2.0, max_age_s=1.0)
    with pytest.raises(ValueError):
        AdaptiveComplementaryFilter().batch(np.zeros((3, 3)), np.zeros((3, 3)), dt=0.01, v_b=np.zeros(3))
