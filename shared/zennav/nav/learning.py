"""What the navigation engine gives to and takes from the learned INS-error models (DESIGN.md section 5).

While GNSS is valid and the filter has converged, every fused GNSS position update yields a LearnSample:
    features (11): mean specific force f_b [m/s^2] and mean angular rate omega_ib_b [rad/s] over the interval
                   since the previous sample (body frame), velocity v_n [m/s] (NED), sin and cos of the yaw;
    targets, as rates over that interval (so windows of any length compare):
      "position" (seed 000): the filter's position correction, INS minus filter, N and E [m/s];
      "velocity" (seed 002: increments of INS minus filter): the velocity correction, N and E [m/s^2].
While no GNSS is fused, every tick (1.5 GNSS intervals) yields a LearnQuery with the same features; the answer,
a predicted rate with its 1-sigma, comes back through Navigator.on_correction as a pseudo-measurement of the
error accrued over the query's interval.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

TARGETS = ("position", "velocity")
FEATURE_NAMES = ("f_x", "f_y", "f_z", "w_x", "w_y", "w_z", "v_n", "v_e", "v_d", "sin_yaw", "cos_yaw")


@dataclass
class LearnSample:
    """One training pair: t_ns, features (11,), dt_s, and the target rates per variant (2,) each."""

    t_ns: int
    features: np.ndarray
    dt_s: float
    position: np.ndarray
    velocity: np.ndarray


@dataclass
class LearnQuery:
    """A request for a predicted INS-error rate over the interval of dt_s seconds ending at t_ns."""

    t_ns: int
    features: np.ndarray
    dt_s: float


class FeatureWindow:
    """Sums of the bias-corrected increments since the last sample or query (cheap per IMU sample)."""

    def __init__(self):
        self.reset()

    def reset(self) -> None:
        self.dtheta = [0.0, 0.0, 0.0]
        self.dvel = [0.0, 0.0, 0.0]
        self.dt = 0.0

    def add(self, dtheta, dvel, dt: float) -> None:
        a, v = self.dtheta, self.dvel
        a[0] += dtheta[0]
        a[1] += dtheta[1]
        a[2] += dtheta[2]
        v[0] += dvel[0]
        v[1] += dvel[1]
        v[2] += dvel[2]
        self.dt += dt

    def features(self, v_n, yaw: float) -> np.ndarray:
        dt = self.dt
        return np.array([*(x / dt for x in self.dvel), *(x / dt for x in self.dtheta), *v_n,
                         math.sin(yaw), math.cos(yaw)])
