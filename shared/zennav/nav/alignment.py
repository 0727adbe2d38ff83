"""Coarse alignment of the strapdown INS: static levelling and gyrocompassing, and in-motion yaw and pitch
from the GNSS velocity (seed 002). Frames: n = NED, b = FRD, Euler ZYX (roll, pitch, yaw) [rad], SI units.

Static (Groves 2013, "Principles of GNSS, Inertial, and Multisensor Integrated Navigation Systems", 2nd ed.,
section 5.6.2; section 14.4.1 for the error budget). At rest f_b = C_bn (0, 0, -g) and
omega_ib_b = C_bn omega_ie_n with omega_ie_n = Omega (cos L, 0, -sin L):
- levelling (eq. 5.101): roll = atan2(-f_y, -f_z), pitch = atan(f_x / sqrt(f_y^2 + f_z^2));
  1-sigma from the accelerometer bias and white noise: sqrt(b_a^2 + vrw^2 / T) / g;
- gyrocompassing (eq. 5.103): the gyro levelled by roll and pitch measures Omega cos L (cos yaw, -sin yaw), so
  sin yaw = -w_y cos roll + w_z sin roll, cos yaw = w_x cos pitch + (w_y sin roll + w_z cos roll) sin pitch;
  1-sigma sqrt(b_g^2 + arw^2 / T) / (Omega cos L) from the gyro, plus tan L times the levelling error. It needs
  a gyro whose bias is well below the horizontal earth rate (about 15 cos L deg/h): refused otherwise.
In motion (seed 002 step S3-1; Groves 2013 section 14.4.2): with the GNSS velocity v_n of a vehicle whose
body x axis moves along its velocity (land vehicles, fixed-wing aircraft): yaw = atan2(v_E, v_N) and
pitch = atan2(-v_D, sqrt(v_N^2 + v_E^2)) (the climb angle); roll 0 with a large variance for ground vehicles.
The yaw 1-sigma is the velocity noise across the track over the speed plus a course allowance (sideslip,
yaw mounting); the climb-angle pitch likewise with a tilt allowance (suspension, pitch mounting).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import earth
from .types import ImuNoise


def level(f_b_mean) -> tuple[float, float]:
    """Roll and pitch [rad] from the mean specific force at rest f_b_mean [m/s^2, body]."""
    fx, fy, fz = (float(x) for x in f_b_mean)
    return math.atan2(-fy, -fz), math.atan2(fx, math.hypot(fy, fz))


def levelling_std(noise: ImuNoise, duration_s: float, g: float = earth.G0) -> float:
    """1-sigma [rad] of levelled roll and pitch over duration_s [s] of rest: accelerometer bias and noise over g."""
    return math.sqrt(noise.accel_bias_std**2 + noise.vrw**2 / duration_s) / g


def gyrocompass(omega_b_mean, roll: float, pitch: float) -> float:
    """Yaw [rad] from the mean angular rate at rest omega_b_mean [rad/s, body] and the levelled roll, pitch [rad]."""
    wx, wy, wz = (float(x) for x in omega_b_mean)
    sr, cr, sp, cp = math.sin(roll), math.cos(roll), math.sin(pitch), math.cos(pitch)
    return math.atan2(-wy * cr + wz * sr, wx * cp + (wy * sr + wz * cr) * sp)


def gyrocompass_std(noise: ImuNoise, lat: float, duration_s: float) -> float:
    """Predicted yaw 1-sigma [rad] of gyrocompassing over duration_s [s] at rest at latitude lat [rad]: gyro bias
    and angle random walk over the horizontal earth rate, plus tan(L) times the levelling error."""
    horizontal_rate = earth.OMEGA_IE * math.cos(lat)
    gyro = math.sqrt(noise.gyro_bias_std**2 + noise.arw**2 / duration_s) / horizontal_rate
    return math.hypot(gyro, math.tan(lat) * levelling_std(noise, duration_s))


def gyrocompass_refusal(noise: ImuNoise, lat: float, duration_s: float, max_yaw_std: float) -> str:
    """Why gyrocompassing over duration_s [s] at latitude lat [rad] is refused for this IMU (noise: the configured
    model), or "" when its predicted yaw 1-sigma is at most max_yaw_std [rad]."""
    yaw_std = gyrocompass_std(noise, lat, duration_s)
    if yaw_std <= max_yaw_std:
        return ""
    return (f"gyrocompassing refused: predicted heading 1-sigma {math.degrees(yaw_std):.1f} deg > "
            f"{math.degrees(max_yaw_std):.1f} deg (gyro bias {math.degrees(noise.gyro_bias_std) * 3600:.2f} deg/h, "
            f"ARW {math.degrees(noise.arw) * 60:.3f} deg/sqrt(h) over {duration_s:.0f} s vs horizontal earth rate "
            f"{math.degrees(earth.OMEGA_IE * math.cos(lat)) * 3600:.2f} deg/h at latitude {math.degrees(lat):.1f} deg)")


@dataclass
class StaticAlignment:
    """Result of a static coarse alignment: euler [rad] (yaw NaN when refused), its 1-sigma [rad] (yaw inf when
    refused) and a one-line message saying what was done or why gyrocompassing was refused."""

    euler: np.ndarray
    std_euler: np.ndarray
    gyrocompassed: bool
    message: str


def static_alignment(f_b_mean, omega_b_mean, lat: float, duration_s: float, noise: ImuNoise,
                     max_yaw_std: float) -> StaticAlignment:
    """Levelling, then gyrocompassing when its predicted yaw 1-sigma is at most max_yaw_std [rad] for this gyro
    (noise: the configured IMU model) at latitude lat [rad] after duration_s [s] at rest."""
    roll, pitch = level(f_b_mean)
    tilt_std = levelling_std(noise, duration_s)
    refusal = gyrocompass_refusal(noise, lat, duration_s, max_yaw_std)
    if refusal:
        return StaticAlignment(np.array([roll, pitch, math.nan]), np.array([tilt_std, tilt_std, math.inf]), False,
                               refusal)
    yaw = gyrocompass(omega_b_mean, roll, pitch)
    yaw_std = gyrocompass_std(noise, lat, duration_s)
    msg = (f"gyrocompassed over {duration_s:.0f} s: yaw {math.degrees(yaw):.2f} deg, 1-sigma "
           f"{math.degrees(yaw_std):.2f} deg")
    return StaticAlignment(np.array([roll, pitch, yaw]), np.array([tilt_std, tilt_std, yaw_std]), True, msg)


def course_alignment(v_n, std_v_n, course_std: float, tilt_std: float) -> tuple[np.ndarray, np.ndarray]:
    """In-motion coarse attitude from the NED velocity v_n [m/s] with 1-sigma std_v_n [m/s]: (euler, std_euler)
    [rad] with roll 0, pitch the climb angle, yaw the course; course_std and tilt_std [rad] are the allowances
    for heading minus course and for roll / pitch minus climb angle (see the module docstring)."""
    vn, ve, vd = (float(x) for x in v_n)
    sn, se, sd = (float(x) for x in std_v_n)
    speed_h = math.hypot(vn, ve)
    yaw = math.atan2(ve, vn)
    pitch = math.atan2(-vd, speed_h)
    across2 = (sn * math.sin(yaw)) ** 2 + (se * math.cos(yaw)) ** 2  # velocity variance across the track
    yaw_std = math.sqrt(across2 / speed_h**2 + course_std**2)
    pitch_std = math.sqrt(sd**2 / speed_h**2 + tilt_std**2)
    return np.array([0.0, pitch, yaw]), np.array([tilt_std, pitch_std, yaw_std])
