"""The error model against the mechanization it linearises, the GNSS and body-velocity measurement Jacobians,
the Joseph update, and the drift of a stationary IMU explained by its biases."""
import math

import numpy as np
import pytest

from zennav.nav import earth
from zennav.nav.aiding import antenna_velocity, body_velocity_model, position_model, velocity_model
from zennav.nav.eskf import ErrorStateKF, discretize, error_model, process_noise_psd
from zennav.nav.navigator import Navigator
from zennav.nav.rotation import euler_to_dcm, euler_to_quat, quat_multiply, rotvec_to_quat
from zennav.nav.strapdown import NavState, mechanize
from zennav.nav.types import ImuNoise, InitialState, NavConfig

EPS = np.array([1.0] * 3 + [0.01] * 3 + [1e-4] * 3 + [1e-5] * 3 + [1e-3] * 3)


def error_between(est: NavState, ref: NavState) -> np.ndarray:
    """(dr_n, dv_n, phi) of est relative to ref, in the filter's error definitions."""
    r_m, r_n = earth.radii(ref.lat)
    dr = [(est.lat - ref.lat) * (r_m + ref.h), (est.lon - ref.lon) * (r_n + ref.h) * math.cos(ref.lat), ref.h - est.h]
    A = ref.C_nb @ est.C_nb.T  # = I + [phi x]
    phi = 0.5 * np.array([A[2, 1] - A[1, 2], A[0, 2] - A[2, 0], A[1, 0] - A[0, 1]])
    return np.concatenate([dr, est.v_n - ref.v_n, phi])


def perturbed(s: NavState, dx: np.ndarray) -> NavState:
    """State whose error relative to s is dx[:9]."""
    r_m, r_n = earth.radii(s.lat)
    q = quat_multiply(rotvec_to_quat(-dx[6:9]), s.q_nb)  # C_hat = (I - [phi x]) C
    return NavState(s.lat + dx[0] / (r_m + s.h), s.lon + dx[1] / ((r_n + s.h) * math.cos(s.lat)), s.h - dx[2],
                    s.vn + dx[3], s.ve + dx[4], s.vd + dx[5], *q)


def run(s0: NavState, bias_err: np.ndarray, steps: int, dt: float, omega_b, f_b):
    """Mechanize `steps` constant-rate IMU intervals with bias estimates off by bias_err (dbg, dba)."""
    s = s0.copy()
    prev_a, prev_v = (0.0,) * 3, (0.0,) * 3
    for _ in range(steps):
        a = tuple(np.asarray(omega_b) * dt - bias_err[:3] * dt)
        v = tuple(np.asarray(f_b) * dt - bias_err[3:] * dt)
        mechanize(s, a, v, prev_a, prev_v, dt)
        prev_a, prev_v = a, v
    return s


def test_error_model_matches_numerical_jacobian_of_mechanization():
    noise = ImuNoise(gyro_bias_tau=1e9, accel_bias_tau=1e9)
    s0 = NavState.from_arrays([math.radians(50.0), 0.3, 300.0], [15.0, -8.0, 0.5],
                              euler_to_quat(np.radians([5.0, -10.0, 120.0])))
    omega_b = np.array([0.02, -0.01, 0.15])  # turning
    f_b = np.array([1.5, 0.8, -9.5])  # accelerating
    dt, steps = 0.01, 100  # 1 s horizon
    nominal = run(s0, np.zeros(6), steps, dt, omega_b, f_b)
    # Model: product of the per-step transition matrices along the nominal trajectory.
    Phi = np.eye(15)
    s = s0.copy()
    for _ in range(steps):
        F = error_model(s.lat, s.h, (s.vn, s.ve, s.vd), s.C_nb, f_b, noise)
        Phi = discretize(F, np.zeros(15), dt)[0] @ Phi
        s = run(s, np.zeros(6), 1, dt, omega_b, f_b)
    Phi_num = np.zeros((15, 15))
    for j in range(15):
        dx = np.zeros(15)
        dx[j] = EPS[j]
        end = run(perturbed(s0, dx), dx[9:], steps, dt, omega_b, f_b)
        Phi_num[:9, j] = error_between(end, nominal) / EPS[j]
        Phi_num[9:, j] = dx[9:] / EPS[j]
    # Compare in perturbation units: the error each unit perturbation causes, scaled by the other states' EPS.
    scaled_num = Phi_num * EPS[None, :] / EPS[:, None]
    scaled_model = Phi * EPS[None, :] / EPS[:, None]
    print('max scaled difference', np.max(np.abs(scaled_num - scaled_model)))
    assert np.max(np.abs(scaled_num - scaled_model)) < 2e-3, np.round(scaled_num - scaled_model, 4)
    # Not vacuous: the couplings that matter are large here.
    assert np.linalg.norm(Phi[3:6, 6:9]) > 5.0 and np.linalg.norm(Phi[0:3, 12:15]) > 0.3


def test_gnss_measurement_jacobians():
    rng = np.random.default_rng(3)
    s = NavState.from_arrays([math.radians(40.0), -1.8, 1600.0], [10.0, 5.0, -0.3],
                             euler_to_quat(np.radians([3.0, 2.0, -60.0])))
    lever_b = np.array([0.8, -0.3, -1.2])
    omega_b = np.array([0.1, -0.2, 0.5])
    fix_llh, fix_v = s.llh + [1e-7, -1e-7, 0.5], s.v_n + [0.1, 0.0, -0.1]
    v_b = s.C_nb.T @ s.v_n + [0.3, -0.2, 0.1]
    z0, H_pos = position_model(s, lever_b, fix_llh, np.zeros(3), 0.0)
    zv0, H_vel = velocity_model(s, lever_b, omega_b, fix_v)
    zb0, H_body = body_velocity_model(s, v_b)
    assert zb0 == pytest.approx([-0.3, 0.2, -0.1])
    for _ in range(20):
        dx = rng.normal(0, 1, 15) * EPS
        est = perturbed(s, dx)
        z1, _ = position_model(est, lever_b, fix_llh, np.zeros(3), 0.0)
        zv1, _ = velocity_model(est, lever_b, omega_b - dx[9:12], fix_v)
        zb1, _ = body_velocity_model(perturbed(s, 0.1 * dx), v_b)  # smaller: the phi * dv term is second order
        assert z1 - z0 == pytest.approx(H_pos @ dx, abs=1e-6)
        assert zv1 - zv0 == pytest.approx(H_vel @ dx, abs=1e-6)
        assert zb1 - zb0 == pytest.approx(H_body @ (0.1 * dx), abs=1e-7)
    assert np.linalg.norm(H_body[:, 6:9]) > 5.0  # attitude couples strongly at this speed: not vacuous
    assert antenna_velocity(s, np.zeros(3), omega_b) == pytest.approx(s.v_n)


def test_joseph_update_keeps_covariance_symmetric_positive_definite():
    rng = np.random.default_rng(4)
    A = rng.normal(size=(15, 15))
    D = np.diag(np.logspace(-4, 2, 15))
    kf = ErrorStateKF(D @ A @ A.T @ D + 1e-12 * np.eye(15))
    for k in range(2000):
        H = rng.normal(size=(3, 15))
        R = np.diag(rng.uniform(1e-6, 10, 3))
        res = kf.update(rng.normal(size=3), H, R, gate=None)
        assert res.fused
        if k % 5 == 0:
            Phi = np.eye(15) + 0.01 * rng.normal(size=(15, 15))
            kf.propagate(Phi, rng.uniform(0, 1e-6, 15), 1.0)
        assert np.array_equal(kf.P, kf.P.T)
        assert np.linalg.eigvalsh(kf.P).min() > 0.0


def test_gate_rejects_outlier_and_leaves_covariance():
    kf = ErrorStateKF(np.eye(15))
    H = np.zeros((3, 15))
    H[:, :3] = np.eye(3)
    P_before = kf.P.copy()
    res = kf.update(np.array([100.0, 0, 0]), H, np.eye(3), gate=20.0)
    assert not res.fused and res.test_ratio > 1 and np.array_equal(kf.P, P_before)


def test_stationary_imu_drifts_only_as_its_biases_explain():
    """Ideal stationary IMU plus constant biases, no aiding: the navigation error equals the error model's
    prediction (Phi over the run applied to the initial bias errors) within 2 %, and is zero without biases."""
    lat, h = math.radians(30.5), 20.0
    eul = np.radians([1.0, -2.0, 30.0])
    C_nb = euler_to_dcm(eul)
    f_b = C_nb.T @ np.array([0.0, 0.0, -earth.gravity(lat, h)])
    omega_b = C_nb.T @ earth.omega_ie_n(lat)
    bias = np.concatenate([np.radians([10.0, -5.0, 8.0]) / 3600.0, [2e-3, -1e-3, 1.5e-3]])  # 10 deg/h, 2 mg
    noise = ImuNoise(gyro_bias_tau=1e12, accel_bias_tau=1e12)
    cfg = NavConfig(imu_noise=noise, outage_timeout_s=1e9)
    dt, T = 0.01, 120.0
    runs = {}
    for name, b in (("clean", np.zeros(6)), ("biased", bias)):
        nav = Navigator(cfg, InitialState(0, np.array([lat, 1.0, h]), np.zeros(3), eul))
        for k in range(1, int(T / dt) + 1):
            nav.on_imu(k * 10_000_000, (omega_b + b[:3]) * dt, (f_b + b[3:]) * dt)
        runs[name] = error_between(nav.state, NavState.from_arrays([lat, 1.0, h], [0, 0, 0], euler_to_quat(eul)))
    assert np.max(np.abs(runs["clean"][:6])) < 1e-6
    F = error_model(lat, h, (0, 0, 0), C_nb, f_b, noise)
    x = np.zeros(15)
    x[9:] = -bias  # bias estimate (zero) minus true bias
    Phi, _ = discretize(F, process_noise_psd(noise), 0.01)
    for _ in range(int(T / 0.01)):
        x = Phi @ x
    predicted, actual = x[:9], runs["biased"]
    assert np.linalg.norm(actual[:3]) > 50.0  # the biases do cause a large drift
    assert np.linalg.norm(actual - predicted) < 0.02 * np.linalg.norm(predicted)


def test_schmidt_update_corrects_only_the_chosen_states():
    rng = np.random.default_rng(6)
    A = rng.normal(size=(15, 15))
    kf = ErrorStateKF(A @ A.T + np.eye(15))
    H = np.zeros((2, 15))
    H[0, 0] = H[1, 1] = 1.0
    res = kf.update(np.array([3.0, -2.0]), H, np.eye(2), gate=None, gain_states=slice(0, 3))
    assert res.fused and np.all(res.dx[3:] == 0.0) and np.any(res.dx[:3] != 0.0)
    assert np.linalg.eigvalsh(kf.P).min() > 0.0


@pytest.mark.parametrize("dof", [1, 2, 3, 4, 6, 12])
@pytest.mark.parametrize("p", [0.9, 0.95, 0.99, 0.9973, 0.999, 0.9999])
def test_chi2_quantile_is_scipy_stats_chi2_ppf_bit_for_bit(p, dof):
    """The gate's chi-square quantile (computed without importing scipy.stats) equals scipy's, to the bit."""
    from scipy.stats import chi2

    from zennav.nav.eskf import chi2_quantile

    assert chi2_quantile(p, dof) == float(chi2.ppf(p, dof))


def test_the_written_out_chi2_quantiles_are_scipys():
    """CHI2_TABLE (the default settings' quantiles, written out: no scipy.special import) holds scipy's floats."""
    from scipy.special import gammaincinv
    from scipy.stats import chi2

    from zennav.nav.eskf import CHI2_TABLE

    assert len(CHI2_TABLE) == 27
    for (p, dof), q in CHI2_TABLE.items():
        assert q == float(2.0 * gammaincinv(dof / 2.0, p)) == float(chi2.ppf(p, dof)), (p, dof)
