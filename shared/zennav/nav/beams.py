"""Janus DVL beam geometry (seed 003, step 1.3).

Four beams point downward, tilted by alpha from the DVL frame's z axis (d: forward-right-down of the DVL), at
azimuths psi_i about z: "+" layout psi_i = 0, 90, 180, 270 deg (beam 1 forward, 2 right, 3 aft, 4 left); "x"
layout the same plus 45 deg. Unit vector of beam i in d (Brokloff 1994, "Matrix algorithm for Doppler sonar
navigation", OCEANS'94; Teledyne RD Instruments, "ADCP coordinate transformation", P/N 951-6079-00, 2010):
    b_i = [sin(alpha) cos(psi_i), sin(alpha) sin(psi_i), cos(alpha)].
A beam velocity is the DVL's velocity over the bottom projected on its beam: v_beam_i = b_i . v_d, i.e.
v_beam = B v_d with B = [b_1; b_2; b_3; b_4] (4 x 3). The DVL's velocity in d from the vehicle's state:
    v_d = C_db (C_bn v_n + omega_nb_b x l_b)     (l_b: lever arm IMU -> DVL, body frame).
"""
from __future__ import annotations

import math

import numpy as np

LAYOUTS = {"+": 0.0, "x": math.pi / 4.0}


def janus_directions(tilt: float, layout: str = "x") -> np.ndarray:
    """B (4 x 3): the unit vectors of the four beams in the DVL frame d; tilt [rad] from d's z axis, layout "+" or
    "x" (module docstring)."""
    if layout not in LAYOUTS:
        raise ValueError(f"DVL layout {layout!r}: accepted {', '.join(LAYOUTS)}")
    psi = LAYOUTS[layout] + np.arange(4) * (math.pi / 2.0)
    s, c = math.sin(tilt), math.cos(tilt)
    return np.column_stack([s * np.cos(psi), s * np.sin(psi), np.full(4, c)])


def beams_from_velocity(v_d: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Beam velocities [m/s] (..., 4) of DVL-frame velocities v_d (..., 3) [m/s]."""
    return np.asarray(v_d, dtype=float) @ B.T
