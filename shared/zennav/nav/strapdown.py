"""Strapdown mechanization from angle and velocity increments, in the NED navigation frame.

The algorithm is the classic two-sample one (Savage 1998, "Strapdown inertial navigation
integration algorithm design", parts 1-2; Shin 2005 thesis ch. 2):

- attitude: body rotation vector with the two-sample coning term, n-frame rotation over the
  interval from earth rate plus transport rate;
- velocity: specific-force increment with the rotation and two-sample sculling terms, rotated to n
  with the half-interval n-frame rotation, plus gravity and Coriolis;
- position: latitude, longitude, height integrated with the trapezoidal velocity.

Earth and transport rates and gravity are evaluated at the start of the interval (their change
over one IMU interval is below 1e-6 of their value for any land, sea or air vehicle).

The step works on Python floats (for 3-vectors plain float arithmetic is several times faster than numpy) in
zennav.nav.kernels, which also compiles it into the per-sample loop of zennav replay.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import kernels
from .rotation import quat_to_dcm, quat_to_euler


@dataclass
class NavState:
    """Navigation state of the IMU: lat, lon [rad], h [m], v_n = (vN, vE, vD) [m/s], q_nb (scalar first)."""

    lat: float
    lon: float
    h: float
    vn: float
    ve: float
    vd: float
    q0: float
    q1: float
    q2: float
    q3: float

    @classmethod
    def from_arrays(cls, llh, v_n, q_nb) -> NavState:
        return cls(*(float(x) for x in (*llh, *v_n, *q_nb)))

    def copy(self) -> NavState:
        return NavState(self.lat, self.lon, self.h, self.vn, self.ve, self.vd, self.q0, self.q1, self.q2, self.q3)

    @property
    def llh(self) -> np.ndarray:
        return np.array([self.lat, self.lon, self.h])

    @property
    def v_n(self) -> np.ndarray:
        return np.array([self.vn, self.ve, self.vd])

    @property
    def q_nb(self) -> np.ndarray:
        return np.array([self.q0, self.q1, self.q2, self.q3])

    @property
    def C_nb(self) -> np.ndarray:
        return quat_to_dcm(self.q_nb)

    @property
    def euler(self) -> np.ndarray:
        return quat_to_euler(self.q_nb)


def mechanize(s: NavState, dtheta, dvel, dtheta_prev, dvel_prev, dt: float, kn=kernels) -> None:
    """Advance s in place by one IMU interval of length dt [s] (zennav.nav.kernels.mechanize).

    dtheta, dvel: bias-corrected angle [rad] and velocity [m/s] increments of this interval, body frame;
    dtheta_prev, dvel_prev: those of the previous interval (zeros at the first step), for coning/sculling;
    kn: the arithmetic, zennav.nav.kernels or its compiled() namespace (the same floats).
    """
    a, u, p, w = dtheta, dvel, dtheta_prev, dvel_prev
    s.lat, s.lon, s.h, s.vn, s.ve, s.vd, s.q0, s.q1, s.q2, s.q3 = kn.mechanize(
        s.lat, s.lon, s.h, s.vn, s.ve, s.vd, s.q0, s.q1, s.q2, s.q3, a[0], a[1], a[2], u[0], u[1], u[2], p[0], p[1],
        p[2], w[0], w[1], w[2], dt)
