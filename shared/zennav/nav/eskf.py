"""Error-state Kalman filter of the strapdown INS (error model in NED, psi-angle form): the 15 INS states below,
and after them any augmented states (``Navigator.add_states``: IMU scale factors, an odometer scale, ...).

Error state x = [dr_n (3, NED metres), dv_n (3, m/s), phi (3, rad), dbg (3, rad/s), dba (3, m/s^2)]
with the definitions (estimate minus truth):
    dr_n = position error in NED metres, dv_n = v_hat - v,
    C_nb_hat = (I - [phi x]) C_nb, dbg = bg_hat - bg, dba = ba_hat - ba,
    bias errors first-order Gauss-Markov.
Continuous model (Shin 2005, eqs. 3.48-3.55; Groves 2013 section 14.2.4 in local-navigation form):
    dr'   = F_rr dr + dv
    dv'   = F_vr dr + F_vv dv + [f_n x] phi - C_nb dba + C_nb w_a
    phi'  = F_pr dr + F_pv dv - [omega_in_n x] phi + C_nb dbg - C_nb w_g
    dbg'  = -dbg / tau_g + w_bg,  dba' = -dba / tau_a + w_ba
IMU scale factors (the 21-state option, as KF-GINS): measured = (1 + s) true + b per axis, compensated
omega = (omega_meas - bg_hat) / (1 + sg_hat), so with dsg = sg_hat - sg, dsa = sa_hat - sa (Groves 2013,
chapter 4's IMU error model in the error equations of section 14.2.4; KF-GINS's 21-state model, with our
estimate-minus-truth signs):
    dv'  += -C_nb diag(f_b) dsa,   phi' += C_nb diag(omega_ib_b) dsg,   dsg' = -dsg / tau + w (Gauss-Markov)
Discretisation: Phi = I + F dt + (F dt)^2 / 2, Qd = (Phi Q Phi' + Q) dt / 2 (trapezoid).
Measurement update in Joseph form with chi-square innovation gating.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from . import kernels
from .types import ImuNoise, InitialState, NavConfig

N_STATES = 15
POS, VEL, ATT, BG, BA = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12), slice(12, 15)


# chi2_quantile of the probabilities in deploy/ins.yaml (gate 0.9999, consistency 0.999, adaptive R and DVL anomaly
# 0.99) and the degrees of freedom they meet (1-6, a window of 10 updates of 1-3): scipy's floats written out, so that
# a replay with the default settings does not import scipy.special (about 0.3 s, issue 17); a test ties them.
_CHI2_ROWS = {  # probability -> the quantiles at 1, 2, 3, 4, 5, 6, 10, 20, 30 degrees of freedom
    0.99: (6.6348966010212145, 9.21034037197618, 11.344866730144373, 13.276704135987622, 15.08627246938899,
           16.811893829770927, 23.209251158954356, 37.56623478662507, 50.89218131151707),
    0.999: (10.827566170662733, 13.815510557964274, 16.26623619623813, 18.46682695290317, 20.515005652432873,
            22.457744484825323, 29.58829844507442, 45.31474661812586, 59.70306430442994),
    0.9999: (15.136705226623606, 18.420680743952584, 21.107513466160444, 23.512742444991076, 25.74483195905612,
             27.85634123601417, 35.564013941952396, 52.3859732730525, 67.63263025741439),
}
CHI2_TABLE = {(p, dof): q for p, row in _CHI2_ROWS.items() for dof, q in zip((1, 2, 3, 4, 5, 6, 10, 20, 30), row)}


def chi2_quantile(p: float, dof: int) -> float:
    """The chi-square quantile of probability p with dof degrees of freedom (the innovation gate):
    2 P^-1(dof/2, p), P the regularised lower incomplete gamma function; the same float operations as
    scipy.stats.chi2.ppf, without importing scipy.stats (slow to import); from CHI2_TABLE where it has (p, dof)."""
    q = CHI2_TABLE.get((p, dof))
    if q is not None:
        return q
    from scipy.special import gammaincinv  # here, not at import: about 0.3 s of a replay's start (issue 17)

    return float(2.0 * gammaincinv(dof / 2.0, p))


def error_model(lat: float, h: float, v_n, C_nb: np.ndarray, f_b, noise: ImuNoise) -> np.ndarray:
    """Continuous-time error dynamics matrix F (15x15) at latitude lat [rad], height h [m],
    velocity v_n [m/s], attitude C_nb and specific force f_b [m/s^2, body] (zennav.nav.kernels.error_model)."""
    F = np.zeros((N_STATES, N_STATES))
    vn, ve, vd = (float(x) for x in v_n)
    fx, fy, fz = (float(x) for x in f_b)
    kernels.error_model(F, lat, h, vn, ve, vd, np.asarray(C_nb, dtype=float), fx, fy, fz,
                        -1.0 / noise.gyro_bias_tau, -1.0 / noise.accel_bias_tau)
    return F


def initial_covariance(initial: InitialState, config: NavConfig) -> np.ndarray:
    """P0 from the initial 1-sigma values (bias 1-sigma: the initial state's, else the IMU model's); the roll/pitch
    uncertainty is rotated by the yaw into N/E."""
    noise = config.imu_noise
    P0 = np.zeros((N_STATES, N_STATES))
    P0[POS, POS] = np.diag(np.square(initial.std_pos_ned))
    P0[VEL, VEL] = np.diag(np.square(initial.std_v_n))
    cy, sy = math.cos(initial.euler[2]), math.sin(initial.euler[2])
    R_yaw = np.array([[cy, -sy], [sy, cy]])
    P0[6:8, 6:8] = R_yaw @ np.diag(np.square(initial.std_euler[:2])) @ R_yaw.T
    P0[8, 8] = initial.std_euler[2] ** 2
    std_bg = initial.std_gyro_bias if initial.std_gyro_bias is not None else np.full(3, noise.gyro_bias_std)
    std_ba = initial.std_accel_bias if initial.std_accel_bias is not None else np.full(3, noise.accel_bias_std)
    P0[BG, BG] = np.diag(np.square(std_bg))
    P0[BA, BA] = np.diag(np.square(std_ba))
    return P0


def scale_factor_coupling(F: np.ndarray, C_nb: np.ndarray, f_b, omega_ib_b, sg: slice, sa: slice) -> None:
    """Fill the columns of the gyro (sg) and accelerometer (sa) scale-factor states in F (see the module
    docstring): specific force f_b [m/s^2] and angular rate omega_ib_b [rad/s], body frame, over the step."""
    (fx, fy, fz), (ox, oy, oz) = ([float(x) for x in v] for v in (f_b, omega_ib_b))
    kernels.scale_factor_coupling(F, np.asarray(C_nb, dtype=float), fx, fy, fz, ox, oy, oz, sg.start, sa.start)


def process_noise_psd(noise: ImuNoise) -> np.ndarray:
    """Diagonal of the continuous process-noise PSD Q in error-state coordinates.

    White noise of an isotropic IMU stays isotropic when rotated by C_nb, so Q is diagonal in n."""
    return np.concatenate(
        [
            np.zeros(3),
            np.full(3, noise.vrw**2),
            np.full(3, noise.arw**2),
            np.full(3, 2.0 * noise.gyro_bias_std**2 / noise.gyro_bias_tau),
            np.full(3, 2.0 * noise.accel_bias_std**2 / noise.accel_bias_tau),
        ]
    )


discretize = kernels.discretize  # (F, q_psd, dt) -> (Phi, Qd): second-order Phi, trapezoidal Qd


@dataclass
class UpdateResult:
    """Outcome of one measurement update: innovation and its covariance S, d2 = nu' S^-1 nu,
    test_ratio = d2 / gate threshold (> 1 means rejected by the gate), and the state correction dx."""

    innovation: np.ndarray
    S: np.ndarray
    d2: float
    test_ratio: float
    fused: bool
    dx: np.ndarray = field(default_factory=lambda: np.zeros(0))


class ErrorStateKF:
    """Covariance bookkeeping of the closed-loop error-state filter (the error estimate is fed back
    to the navigation state after every update, so the a-priori error estimate is always zero)."""

    def __init__(self, P0: np.ndarray):
        self.P = np.array(P0, dtype=float)

    def propagate(self, Phi: np.ndarray, q_psd: np.ndarray, dt: float, kn=kernels) -> None:
        """P <- Phi P Phi' + Qd with the trapezoidal Qd of the process-noise PSD diagonal q_psd over dt [s]
        (zennav.nav.kernels.propagate); kn: the arithmetic, zennav.nav.kernels or its compiled() namespace."""
        self.P = kn.propagate(self.P, Phi, q_psd, dt)

    def update(self, z: np.ndarray, H: np.ndarray, R: np.ndarray, gate: float | None,
               gain_states: slice | None = None, PHt: np.ndarray | None = None) -> UpdateResult:
        """Joseph-form update with measurement z = H x + v, v ~ N(0, R).

        gate: chi-square threshold on d2 (None: always fuse). Rejected updates leave P unchanged.
        H has one column per state of P; PHt: P H' when the caller has it already.
        gain_states: correct only these states (Schmidt "consider" update: the other rows of the gain are zero;
        the Joseph form keeps P right for any gain)."""
        P = self.P
        if PHt is None:
            PHt = P @ H.T
        S = H @ PHt + R
        S = 0.5 * (S + S.T)
        S_inv = small_inverse(S)
        d2 = float(z @ (S_inv @ z))
        ratio = d2 / gate if gate else 0.0
        n = P.shape[0]
        if gate is not None and not d2 <= gate:
            return UpdateResult(z, S, d2, ratio, False, np.zeros(n))
        K = PHt @ S_inv
        if gain_states is not None:
            keep = np.zeros(n, dtype=bool)
            keep[gain_states] = True
            K[~keep] = 0.0
        I_KH = K @ H
        np.negative(I_KH, out=I_KH)
        I_KH.ravel()[:: n + 1] += 1.0
        P1 = I_KH @ P @ I_KH.T + K @ R @ K.T
        self.P = 0.5 * (P1 + P1.T)
        return UpdateResult(z, S, d2, ratio, True, K @ z)


def small_inverse(S: np.ndarray) -> np.ndarray:
    """Inverse of a small square matrix S (an innovation covariance H P H' + R: positive definite, conditioned by
    R): by cofactors (Cramer's rule) up to 3 x 3, a few float operations where a numpy.linalg call costs tens of
    microseconds (issue 17); LAPACK above."""
    m = S.shape[0]
    if m == 1:
        return 1.0 / S
    if m == 2:
        (a, b), (c, d) = S.tolist()
        det = a * d - b * c
        return np.array([[d / det, -b / det], [-c / det, a / det]])
    if m == 3:
        (a, b, c), (d, e, f), (g, h, i) = S.tolist()
        c00, c01, c02 = e * i - f * h, f * g - d * i, d * h - e * g
        det = a * c00 + b * c01 + c * c02
        return np.array([[c00 / det, (c * h - b * i) / det, (b * f - c * e) / det],
                         [c01 / det, (a * i - c * g) / det, (c * d - a * f) / det],
                         [c02 / det, (b * g - a * h) / det, (a * e - b * d) / det]])
    return np.linalg.inv(S)
