"""WGS-84 earth model in the navigation frame n = NED.

Latitude/longitude in radians, heights ellipsoidal in metres, rates in rad/s.
Normal gravity: Somigliana closed form with the standard free-air height terms
(NIMA TR8350.2, eq. 4-1 and 4-3), the same as Groves (2013) eq. 2.134/2.139.
"""
from __future__ import annotations

import math
from typing import TypeVar

import numpy as np

A = 6378137.0  # semi-major axis [m]
F = 1.0 / 298.257223563  # flattening
E2 = F * (2.0 - F)  # first eccentricity squared
B = A * (1.0 - F)  # semi-minor axis [m]
OMEGA_IE = 7.2921151467e-5  # earth rotation rate [rad/s]
GM = 3.986004418e14  # gravitational constant [m^3/s^2]
GAMMA_E = 9.7803253359  # normal gravity at the equator [m/s^2]
GAMMA_P = 9.8321849378  # normal gravity at the poles [m/s^2]
_K_SOMIGLIANA = B * GAMMA_P / (A * GAMMA_E) - 1.0
_M_RATIO = OMEGA_IE**2 * A**2 * B / GM
G0 = 9.80665  # standard gravity, for unit conversions only [m/s^2]

# a latitude (or height) argument: one float (per-sample loops) or an array of them (a whole trajectory)
Real = TypeVar("Real", float, np.ndarray)


def _xp(x):
    """math for Python floats (the fast scalar path of per-sample loops), numpy for arrays."""
    return math if isinstance(x, float) else np


def radii(lat: Real) -> tuple[Real, Real]:
    """Meridian (R_M, north-south) and prime-vertical (R_N, east-west) radii of curvature [m]; lat scalar or array."""
    xp = _xp(lat)
    s2 = xp.sin(lat) ** 2
    w = xp.sqrt(1.0 - E2 * s2)
    return A * (1.0 - E2) / (w * w * w), A / w


def gravity_sw(s2, sw, h):
    """Normal gravity [m/s^2] from sin^2(latitude) s2, sw = sqrt(1 - E2 s2) and height h [m]; floats or arrays
    (arithmetic only: the compiled navigation kernels call it, zennav.nav.kernels)."""
    g_surface = GAMMA_E * (1.0 + _K_SOMIGLIANA * s2) / sw
    return g_surface * (1.0 - 2.0 / A * (1.0 + F + _M_RATIO - 2.0 * F * s2) * h + 3.0 / A**2 * h * h)


def gravity_sin2(s2, h):
    """Normal gravity [m/s^2] from sin^2(latitude) s2 and height h [m]; floats or arrays. The square root is sqrt
    (not ** 0.5, libm's pow, which differs from the compiled kernels' sqrt in the last bit of some values)."""
    return gravity_sw(s2, _xp(s2).sqrt(1.0 - E2 * s2), h)


def gravity(lat: Real, h: Real | float) -> Real:
    """Magnitude of normal gravity [m/s^2] at geodetic latitude lat [rad] and height h [m]; points down in n.
    lat, h scalars or arrays."""
    return gravity_sin2(_xp(lat).sin(lat) ** 2, h)


def omega_ie_n(lat: Real) -> np.ndarray:
    """Earth rate resolved in NED [rad/s]: (3,) for a scalar lat, (N, 3) for lat of shape (N,)."""
    xp = _xp(lat)
    return np.array([OMEGA_IE * xp.cos(lat), 0.0 * lat, -OMEGA_IE * xp.sin(lat)]).T


def omega_en_n(lat: Real, h: Real | float, v_n) -> np.ndarray:
    """Transport rate (rotation of n relative to e) resolved in NED [rad/s] for velocity v_n [m/s];
    (3,) for scalars, (N, 3) for lat, h of shape (N,) and v_n of shape (N, 3)."""
    r_m, r_n = radii(lat)
    vn, ve = np.asarray(v_n).T[:2]
    return np.array([ve / (r_n + h), -vn / (r_m + h), -ve * _xp(lat).tan(lat) / (r_n + h)]).T


def llh_to_ecef(llh) -> np.ndarray:
    """Geodetic (lat [rad], lon [rad], h [m]) -> ECEF [m]; works on (3,) or (N, 3)."""
    llh = np.asarray(llh, dtype=float)
    lat, lon, h = llh[..., 0], llh[..., 1], llh[..., 2]
    r_n = A / np.sqrt(1.0 - E2 * np.sin(lat) ** 2)
    return np.stack(
        [
            (r_n + h) * np.cos(lat) * np.cos(lon),
            (r_n + h) * np.cos(lat) * np.sin(lon),
            (r_n * (1.0 - E2) + h) * np.sin(lat),
        ],
        axis=-1,
    )


def ecef_to_llh(r_e) -> np.ndarray:
    """ECEF [m] -> geodetic (lat [rad], lon [rad], h [m]); Bowring's method with one refinement, (3,) or (N, 3)."""
    r_e = np.asarray(r_e, dtype=float)
    x, y, z = r_e[..., 0], r_e[..., 1], r_e[..., 2]
    p = np.hypot(x, y)
    lon = np.arctan2(y, x)
    ep2 = E2 / (1.0 - E2)
    lat = np.arctan2(z, p * (1.0 - E2))
    for _ in range(3):
        theta = np.arctan2(z * A, p * B)
        lat = np.arctan2(z + ep2 * B * np.sin(theta) ** 3, p - E2 * A * np.cos(theta) ** 3)
    sl = np.sin(lat)
    r_n = A / np.sqrt(1.0 - E2 * sl**2)
    h = p * np.cos(lat) + (z + E2 * r_n * sl) * sl - r_n  # well conditioned at every latitude
    return np.stack([lat, lon, h], axis=-1)


def C_en(lat: float, lon: float) -> np.ndarray:
    """Rotation mapping NED coordinates to ECEF coordinates at (lat, lon) [rad]."""
    sl, cl, so, co = math.sin(lat), math.cos(lat), math.sin(lon), math.cos(lon)
    return np.array(
        [
            [-sl * co, -so, -cl * co],
            [-sl * so, co, -cl * so],
            [cl, 0.0, -sl],
        ]
    )


def llh_to_ned(llh, llh_ref) -> np.ndarray:
    """Exact NED offsets [m] of points llh ((3,) or (N, 3)) from the reference point llh_ref."""
    d_e = llh_to_ecef(llh) - llh_to_ecef(llh_ref)
    return d_e @ C_en(llh_ref[0], llh_ref[1])


def ned_to_llh(r_n, llh_ref) -> np.ndarray:
    """Inverse of llh_to_ned: NED offsets [m] from llh_ref -> geodetic (lat, lon, h)."""
    r_e = llh_to_ecef(llh_ref) + np.asarray(r_n, dtype=float) @ C_en(llh_ref[0], llh_ref[1]).T
    return ecef_to_llh(r_e)


def ned_to_dllh(d_ned, lat, h) -> tuple:
    """Small NED offset d_ned = (dN, dE, dD) [m] at latitude lat [rad], height h [m] -> (dlat, dlon, dh) [rad, rad, m]
    (curvilinear, first order); floats, or arrays of one shape. Inlined in strapdown.mechanize (hot loop)."""
    r_m, r_n = radii(lat)
    d_n, d_e, d_d = d_ned
    return d_n / (r_m + h), d_e / ((r_n + h) * _xp(lat).cos(lat)), -d_d


def dllh_to_ned(dllh, lat, h) -> tuple:
    """Inverse of ned_to_dllh: (dlat, dlon, dh) [rad, rad, m] at latitude lat [rad], height h [m] -> small NED
    offset (dN, dE, dD) [m]; floats, or arrays of one shape."""
    r_m, r_n = radii(lat)
    d_lat, d_lon, d_h = dllh
    return d_lat * (r_m + h), d_lon * (r_n + h) * _xp(lat).cos(lat), -d_h


def dr_to_dllh(lat: Real, h: Real | float) -> np.ndarray:
    """Diagonal of D^-1 (ned_to_dllh of a 1 m offset on each axis): (3,) for scalars, (N, 3) for arrays of
    shape (N,)."""
    return np.array(ned_to_dllh((1.0, 1.0, 1.0 + 0.0 * (lat + h)), lat, h)).T
