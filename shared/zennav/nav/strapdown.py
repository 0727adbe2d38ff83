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

The step works on Python floats: for 3-vectors plain float arithmetic is several times faster
than numpy, and this function runs once per IMU sample.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import earth
from .rotation import quat_to_dcm, quat_to_euler, rotvec_quat_xyz

_OMEGA = earth.OMEGA_IE
_A = earth.A
_E2 = earth.E2


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


def mechanize(s: NavState, dtheta, dvel, dtheta_prev, dvel_prev, dt: float) -> None:
    """Advance s in place by one IMU interval of length dt [s].

    dtheta, dvel: bias-corrected angle [rad] and velocity [m/s] increments of this interval, body frame;
    dtheta_prev, dvel_prev: those of the previous interval (zeros at the first step), for coning/sculling.
    """
    ax, ay, az = dtheta
    ux, uy, uz = dvel
    px, py, pz = dtheta_prev
    wx, wy, wz = dvel_prev
    lat, h = s.lat, s.h
    vn, ve, vd = s.vn, s.ve, s.vd

    # Earth model at the start of the interval.
    sl, cl = math.sin(lat), math.cos(lat)
    w = 1.0 - _E2 * sl * sl
    sw = math.sqrt(w)
    r_n = _A / sw
    r_m = r_n * (1.0 - _E2) / w
    rmh, rnh = r_m + h, r_n + h
    tl = sl / cl
    wie_n, wie_d = _OMEGA * cl, -_OMEGA * sl
    wen_n, wen_e, wen_d = ve / rnh, -vn / rmh, -ve * tl / rnh
    g = earth.gravity_sin2(sl * sl, h)

    # Specific-force increment in b: rotation + two-sample sculling (Savage 1998).
    fx = ux + 0.5 * (ay * uz - az * uy) + ((py * uz - pz * uy) + (wy * az - wz * ay)) / 12.0
    fy = uy + 0.5 * (az * ux - ax * uz) + ((pz * ux - px * uz) + (wz * ax - wx * az)) / 12.0
    fz = uz + 0.5 * (ax * uy - ay * ux) + ((px * uy - py * ux) + (wx * ay - wy * ax)) / 12.0

    # Rotate to n with C_nb(k-1), then by (I - 0.5 zeta x) for the n-frame rotation over the interval.
    q0, q1, q2, q3 = s.q0, s.q1, s.q2, s.q3
    c00 = q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3
    c01 = 2.0 * (q1 * q2 - q0 * q3)
    c02 = 2.0 * (q1 * q3 + q0 * q2)
    c10 = 2.0 * (q1 * q2 + q0 * q3)
    c11 = q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3
    c12 = 2.0 * (q2 * q3 - q0 * q1)
    c20 = 2.0 * (q1 * q3 - q0 * q2)
    c21 = 2.0 * (q2 * q3 + q0 * q1)
    c22 = q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3
    gn = c00 * fx + c01 * fy + c02 * fz
    ge = c10 * fx + c11 * fy + c12 * fz
    gd = c20 * fx + c21 * fy + c22 * fz
    zn, ze, zd = (wie_n + wen_n) * dt, wen_e * dt, (wie_d + wen_d) * dt
    dvn = gn - 0.5 * (ze * gd - zd * ge)
    dve = ge - 0.5 * (zd * gn - zn * gd)
    dvd = gd - 0.5 * (zn * ge - ze * gn)

    # Gravity and Coriolis: (g_n - (2 omega_ie_n + omega_en_n) x v_n) dt.
    cn, ce, cd = 2.0 * wie_n + wen_n, wen_e, 2.0 * wie_d + wen_d
    vn1 = vn + dvn - (ce * vd - cd * ve) * dt
    ve1 = ve + dve - (cd * vn - cn * vd) * dt
    vd1 = vd + dvd + (g - (cn * ve - ce * vn)) * dt

    # Position with the trapezoidal velocity; radii at the mid height.
    h1 = h - 0.5 * (vd + vd1) * dt
    hm = 0.5 * (h + h1)
    lat1 = lat + 0.5 * (vn + vn1) * dt / (r_m + hm)
    latm = 0.5 * (lat + lat1)
    slm = math.sin(latm)
    r_nm = _A / math.sqrt(1.0 - _E2 * slm * slm)
    s.lon += 0.5 * (ve + ve1) * dt / ((r_nm + hm) * math.cos(latm))
    s.lat, s.h = lat1, h1
    s.vn, s.ve, s.vd = vn1, ve1, vd1

    # Attitude: q_nb(k) = q(-zeta) * q_nb(k-1) * q(phi), phi with the two-sample coning term.
    b0, b1, b2, b3 = rotvec_quat_xyz(
        ax + (py * az - pz * ay) / 12.0, ay + (pz * ax - px * az) / 12.0, az + (px * ay - py * ax) / 12.0
    )
    r0 = q0 * b0 - q1 * b1 - q2 * b2 - q3 * b3
    r1 = q0 * b1 + q1 * b0 + q2 * b3 - q3 * b2
    r2 = q0 * b2 - q1 * b3 + q2 * b0 + q3 * b1
    r3 = q0 * b3 + q1 * b2 - q2 * b1 + q3 * b0
    n0, n1, n2, n3 = rotvec_quat_xyz(-zn, -ze, -zd)
    t0 = n0 * r0 - n1 * r1 - n2 * r2 - n3 * r3
    t1 = n0 * r1 + n1 * r0 + n2 * r3 - n3 * r2
    t2 = n0 * r2 - n1 * r3 + n2 * r0 + n3 * r1
    t3 = n0 * r3 + n1 * r2 - n2 * r1 + n3 * r0
    norm = 1.0 / math.sqrt(t0 * t0 + t1 * t1 + t2 * t2 + t3 * t3)
    if t0 < 0.0:
        norm = -norm
    s.q0, s.q1, s.q2, s.q3 = t0 * norm, t1 * norm, t2 * norm, t3 * norm
