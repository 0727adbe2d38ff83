"""zennav's frames (navigation NED, body FRD) <-> ROS REP-103/105's (ENU, body FLU), converted once at the edge:
the ROS 2 bridge and the Foxglove views of recordings use these and nothing else.

``C_enu_ned`` maps NED coordinates to ENU (swap north/east, negate down); ``C_frd_flu`` maps FLU body coordinates
to FRD (negate y and z). Both are their own inverse. An orientation q_nb (FRD body -> NED) becomes
C_enu_flu = C_enu_ned C_nb C_frd_flu, the ROS orientation of base_link in an ENU frame.
"""
from __future__ import annotations

import numpy as np

from .nav.rotation import dcm_to_quat, quat_to_dcm

C_ENU_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
C_FRD_FLU = np.diag([1.0, -1.0, -1.0])


def ned_to_enu(v_ned) -> np.ndarray:
    """A vector (or (N, 3) rows) NED -> ENU; the same matrix maps ENU -> NED."""
    return np.asarray(v_ned, dtype=float) @ C_ENU_NED.T


def frd_to_flu(v_frd) -> np.ndarray:
    """A body vector FRD -> FLU; the same matrix maps FLU -> FRD."""
    return np.asarray(v_frd, dtype=float) @ C_FRD_FLU.T


def q_nb_to_q_enu_flu(q_nb) -> np.ndarray:
    """Orientation FRD -> NED (scalar first) -> FLU -> ENU (scalar first)."""
    return dcm_to_quat(C_ENU_NED @ quat_to_dcm(np.asarray(q_nb, dtype=float)) @ C_FRD_FLU)


def q_enu_flu_to_q_nb(q_enu_flu) -> np.ndarray:
    """Orientation FLU -> ENU (scalar first) -> FRD -> NED (scalar first)."""
    return dcm_to_quat(C_ENU_NED @ quat_to_dcm(np.asarray(q_enu_flu, dtype=float)) @ C_FRD_FLU)


def cov_ned_to_enu(cov_ned) -> np.ndarray:
    """A 3x3 covariance NED -> ENU (and back)."""
    c = np.asarray(cov_ned, dtype=float)
    return C_ENU_NED @ c @ C_ENU_NED.T
