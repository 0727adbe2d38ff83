"""Measurement models of the error-state filter: predicted-minus-observed antenna position and velocity (GNSS)
and body-frame velocity (learned pseudo-measurement), with their Jacobians H with respect to the 15-element
error state (see eskf.py).

Antenna at lever arm l_b (FRD, from the IMU):
    r_ant = r + C_nb l_b,  v_ant = v_n + C_nb (omega_ib_b x l_b) - omega_in_n x (C_nb l_b).
With C_nb_hat = (I - [phi x]) C_nb and omega_ib_b_hat = omega_ib_b - dbg (Groves 2013, section 14.3.1):
    H_pos = [I, 0, [C_nb l x], 0, 0]
    H_vel = [0, I, [C_nb (omega x l) x] - [omega_in_n x][C_nb l x], C_nb [l x], 0]
Body velocity v_b = C_bn v_n: C_bn_hat v_hat = C_bn (I + [phi x]) (v_n + dv) ~ v_b + C_bn dv - C_bn [v_n x] phi,
    H_body = [0, C_bn, -C_bn [v_n x], 0, 0]
"""
from __future__ import annotations

import math

import numpy as np

from . import earth, kernels
from .eskf import ATT, N_STATES, VEL
from .rotation import skew
from .strapdown import NavState


def _dcm(s: NavState) -> tuple:
    """The nine elements of C_nb, row by row, as Python floats (zennav.nav.kernels.quat_dcm)."""
    return tuple(kernels.quat_dcm(s.q0, s.q1, s.q2, s.q3).ravel().tolist())


def _lever_terms(s: NavState, lever_b, omega_ib_b) -> tuple:
    """C_nb (9 floats), lever_n = C_nb l_b [m], r_n = C_nb (omega_ib_b x l_b) [m/s] and omega_in_n [rad/s] as
    float triples: the antenna terms on Python floats (a few microseconds where numpy's small arrays cost tens)."""
    C = c00, c01, c02, c10, c11, c12, c20, c21, c22 = _dcm(s)
    lx, ly, lz = (float(x) for x in lever_b)
    ox, oy, oz = (float(x) for x in omega_ib_b)
    wx, wy, wz = oy * lz - oz * ly, oz * lx - ox * lz, ox * ly - oy * lx  # omega_ib_b x l_b
    lever_n = (c00 * lx + c01 * ly + c02 * lz, c10 * lx + c11 * ly + c12 * lz, c20 * lx + c21 * ly + c22 * lz)
    r_n = (c00 * wx + c01 * wy + c02 * wz, c10 * wx + c11 * wy + c12 * wz, c20 * wx + c21 * wy + c22 * wz)
    lat, h = s.lat, s.h
    r_m, r_nv = earth.radii(lat)
    omega_in_n = (earth.OMEGA_IE * math.cos(lat) + s.ve / (r_nv + h), -s.vn / (r_m + h),
                  -earth.OMEGA_IE * math.sin(lat) - s.ve * math.tan(lat) / (r_nv + h))
    return C, lever_n, r_n, omega_in_n


def _antenna_velocity(s: NavState, lever_n: tuple, r_n: tuple, omega_in_n: tuple) -> tuple:
    """v_ant = v_n + C_nb (omega_ib_b x l_b) - omega_in_n x (C_nb l_b) [m/s, NED] from _lever_terms."""
    (on, oe, od), (ln, le, ld) = omega_in_n, lever_n
    return (s.vn + r_n[0] - (oe * ld - od * le), s.ve + r_n[1] - (od * ln - on * ld),
            s.vd + r_n[2] - (on * le - oe * ln))


def position_model(s: NavState, lever_b: np.ndarray, fix_llh: np.ndarray, v_ant_n: np.ndarray, age_s: float):
    """z = INS antenna position minus the fix [m, NED] and H (3x15). A fix age_s seconds older than the state
    is moved forward along the antenna velocity v_ant_n first."""
    lx, ly, lz = (float(x) for x in lever_b)
    c00, c01, c02, c10, c11, c12, c20, c21, c22 = _dcm(s)
    ln, le, ld = c00 * lx + c01 * ly + c02 * lz, c10 * lx + c11 * ly + c12 * lz, c20 * lx + c21 * ly + c22 * lz
    f_lat, f_lon, f_h = (float(x) for x in fix_llh)
    d_n, d_e, d_d = earth.dllh_to_ned((s.lat - f_lat, s.lon - f_lon, s.h - f_h), s.lat, s.h)
    va_n, va_e, va_d = (float(x) * age_s for x in v_ant_n)
    z = np.array([d_n + ln - va_n, d_e + le - va_e, d_d + ld - va_d])
    H = np.zeros((3, N_STATES))
    H[0, 0] = H[1, 1] = H[2, 2] = 1.0
    H[0, 7], H[0, 8], H[1, 6], H[1, 8], H[2, 6], H[2, 7] = -ld, le, ld, -ln, -le, ln  # [lever_n x]
    return z, H


def antenna_velocity(s: NavState, lever_b: np.ndarray, omega_ib_b: np.ndarray) -> np.ndarray:
    """NED velocity of the antenna [m/s] given the body rate omega_ib_b [rad/s]."""
    _, lever_n, r_n, omega_in_n = _lever_terms(s, lever_b, omega_ib_b)
    return np.array(_antenna_velocity(s, lever_n, r_n, omega_in_n))


def velocity_model(s: NavState, lever_b: np.ndarray, omega_ib_b: np.ndarray, fix_v_n: np.ndarray):
    """z = INS antenna velocity minus the GNSS velocity [m/s, NED] and H (3x15)."""
    C, lever_n, r_n, omega_in_n = _lever_terms(s, lever_b, omega_ib_b)
    va_n, va_e, va_d = _antenna_velocity(s, lever_n, r_n, omega_in_n)
    f_n, f_e, f_d = (float(x) for x in fix_v_n)
    z = np.array([va_n - f_n, va_e - f_e, va_d - f_d])
    H = np.zeros((3, N_STATES))
    H[0, 3] = H[1, 4] = H[2, 5] = 1.0
    # attitude: [r_n x] - [omega_in_n x][lever_n x], with [a x][b x] = b a' - (a . b) I
    (rn, re, rd), (a0, a1, a2), (b0, b1, b2) = r_n, omega_in_n, lever_n
    ab = a0 * b0 + a1 * b1 + a2 * b2
    H[0, 6], H[0, 7], H[0, 8] = -(b0 * a0 - ab), -rd - b0 * a1, re - b0 * a2
    H[1, 6], H[1, 7], H[1, 8] = rd - b1 * a0, -(b1 * a1 - ab), -rn - b1 * a2
    H[2, 6], H[2, 7], H[2, 8] = -re - b2 * a0, rn - b2 * a1, -(b2 * a2 - ab)
    # gyro bias: C_nb [l_b x]
    lx, ly, lz = (float(x) for x in lever_b)
    for i in range(3):
        ci0, ci1, ci2 = C[3 * i], C[3 * i + 1], C[3 * i + 2]
        H[i, 9], H[i, 10], H[i, 11] = ci1 * lz - ci2 * ly, ci2 * lx - ci0 * lz, ci0 * ly - ci1 * lx
    return z, H


def body_velocity_model(s: NavState, v_b: np.ndarray):
    """z = INS velocity in the body frame minus v_b [m/s, FRD] and H (3x15)."""
    C_bn = s.C_nb.T
    v_n = s.v_n
    H = np.zeros((3, N_STATES))
    H[:, VEL] = C_bn
    H[:, ATT] = -C_bn @ skew(v_n)
    return C_bn @ v_n - v_b, H
