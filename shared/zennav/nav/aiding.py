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

import numpy as np

from . import earth
from .eskf import ATT, BG, N_STATES, POS, VEL
from .rotation import skew
from .strapdown import NavState


def position_model(s: NavState, lever_b: np.ndarray, fix_llh: np.ndarray, v_ant_n: np.ndarray, age_s: float):
    """z = INS antenna position minus the fix [m, NED] and H (3x15). A fix age_s seconds older than the state
    is moved forward along the antenna velocity v_ant_n first."""
    lever_n = s.C_nb @ lever_b
    d_n, d_e, d_d = earth.dllh_to_ned((s.lat - fix_llh[0], s.lon - fix_llh[1], s.h - fix_llh[2]), s.lat, s.h)
    z = np.array([d_n + lever_n[0], d_e + lever_n[1], d_d + lever_n[2]]) - v_ant_n * age_s
    H = np.zeros((3, N_STATES))
    H[:, POS] = np.eye(3)
    H[:, ATT] = skew(lever_n)
    return z, H


def antenna_velocity(s: NavState, lever_b: np.ndarray, omega_ib_b: np.ndarray) -> np.ndarray:
    """NED velocity of the antenna [m/s] given the body rate omega_ib_b [rad/s]."""
    C_nb = s.C_nb
    omega_in_n = earth.omega_ie_n(s.lat) + earth.omega_en_n(s.lat, s.h, (s.vn, s.ve, s.vd))
    return s.v_n + C_nb @ (skew(omega_ib_b) @ lever_b) - skew(omega_in_n) @ (C_nb @ lever_b)


def velocity_model(s: NavState, lever_b: np.ndarray, omega_ib_b: np.ndarray, fix_v_n: np.ndarray):
    """z = INS antenna velocity minus the GNSS velocity [m/s, NED] and H (3x15)."""
    C_nb = s.C_nb
    omega_in_n = earth.omega_ie_n(s.lat) + earth.omega_en_n(s.lat, s.h, (s.vn, s.ve, s.vd))
    z = antenna_velocity(s, lever_b, omega_ib_b) - fix_v_n
    H = np.zeros((3, N_STATES))
    H[:, VEL] = np.eye(3)
    H[:, ATT] = skew(C_nb @ (skew(omega_ib_b) @ lever_b)) - skew(omega_in_n) @ skew(C_nb @ lever_b)
    H[:, BG] = C_nb @ skew(lever_b)
    return z, H


def body_velocity_model(s: NavState, v_b: np.ndarray):
    """z = INS velocity in the body frame minus v_b [m/s, FRD] and H (3x15)."""
    C_bn = s.C_nb.T
    v_n = s.v_n
    H = np.zeros((3, N_STATES))
    H[:, VEL] = C_bn
    H[:, ATT] = -C_bn @ skew(v_n)
    return C_bn @ v_n - v_b, H
