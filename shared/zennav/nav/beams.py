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


# Partial beams (seed step 2.4). Opposite beams (1-3, 2-4: azimuths psi and psi + 180 deg) have b_i + b_j =
# 2 cos(alpha) e_z, so v_1 + v_3 = v_2 + v_4 = 2 cos(alpha) v_d,z for any velocity: with 3 valid beams the fourth is
# v_missing = (sum of the other pair) - (its opposite beam), exact. With 2 adjacent ("orthogonal") valid beams the
# seed assumes no vertical velocity (v_d,z = 0: the AUV does not heave; wrong when it rises or sinks with the swell):
# each missing beam is minus its opposite, v_3 = -v_1, v_4 = -v_2. Two opposite ("parallel") beams give only the
# velocity in their plane, one beam or none less: no reconstruction, the missing beams stay the INS-predicted ones
# (no information).
BEAM_CASES = ("4", "3", "2_orthogonal", "2_parallel", "1", "0")
_OPPOSITE = (2, 3, 0, 1)


def beam_case(valid) -> str:
    """Which partial-beam case (BEAM_CASES) a validity mask (4,) of beams 1..4 is."""
    v = np.asarray(valid, dtype=bool)
    n = int(v.sum())
    if n != 2:
        return str(n)
    i, j = np.flatnonzero(v)
    return "2_parallel" if _OPPOSITE[i] == j else "2_orthogonal"


def reconstruct_beams(beams, valid) -> np.ndarray | None:
    """All four beam velocities [m/s] from the valid ones (module notes above): the valid beams as given, the missing
    ones reconstructed; None in the cases without a reconstruction (2 parallel, 1 or 0 valid beams)."""
    v = np.asarray(valid, dtype=bool)
    out = np.where(v, np.asarray(beams, dtype=float), 0.0)
    case = beam_case(v)
    if case == "4":
        return out
    if case == "3":
        k = int(np.flatnonzero(~v)[0])
        pair = [i for i in range(4) if i not in (k, _OPPOSITE[k])]
        out[k] = out[pair[0]] + out[pair[1]] - out[_OPPOSITE[k]]
        return out
    if case == "2_orthogonal":
        for k in np.flatnonzero(~v).tolist():
            out[k] = -out[_OPPOSITE[k]]
        return out
    return None


def velocity_from_beams(beams, valid, B: np.ndarray) -> np.ndarray | None:
    """Least-squares DVL-frame velocity v_d [m/s] (3,) from the valid beams ([m/s], (4,)) of directions B (4 x 3), with
    the partial-beam reconstruction where fewer than 3 are valid; None where there is none (reconstruct_beams)."""
    v = np.asarray(valid, dtype=bool)
    full = np.asarray(beams, dtype=float) if v.sum() >= 3 else reconstruct_beams(beams, v)
    if full is None:
        return None
    use = v if v.sum() >= 3 else np.ones(4, dtype=bool)
    return np.linalg.lstsq(B[use], full[use], rcond=None)[0]
