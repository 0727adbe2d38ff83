"""Rotations in the conventions of README.md (Conventions).

- ``C_ab`` maps frame-b coordinates to frame a: ``v_a = C_ab @ v_b``.
- Quaternions are scalar first, Hamilton product; ``q_ab`` represents the same rotation as ``C_ab``.
- Euler angles are ZYX (yaw about z, then pitch about the new y, then roll about the newest x),
  ``euler = (roll, pitch, yaw)`` in radians, and ``C_nb = Rz(yaw) @ Ry(pitch) @ Rx(roll)``.
- A rotation vector ``rv`` (axis times angle, rad) is the quaternion ``exp(rv / 2)``.
"""
from __future__ import annotations

import math

import numpy as np


def skew(v) -> np.ndarray:
    """Cross-product matrix: ``skew(a) @ b == cross(a, b)``."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def quat_multiply(p, q) -> np.ndarray:
    """Hamilton product p*q (scalar first); q_ac = quat_multiply(q_ab, q_bc)."""
    p0, p1, p2, p3 = p
    q0, q1, q2, q3 = q
    return np.array(
        [
            p0 * q0 - p1 * q1 - p2 * q2 - p3 * q3,
            p0 * q1 + p1 * q0 + p2 * q3 - p3 * q2,
            p0 * q2 - p1 * q3 + p2 * q0 + p3 * q1,
            p0 * q3 + p1 * q2 - p2 * q1 + p3 * q0,
        ]
    )


def quat_conjugate(q) -> np.ndarray:
    """Inverse of a unit quaternion: q_ba from q_ab."""
    return np.array([q[0], -q[1], -q[2], -q[3]])


def quat_normalize(q) -> np.ndarray:
    """Unit quaternion with a non-negative scalar part."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q)
    return -q if q[0] < 0.0 else q


def quat_to_dcm(q) -> np.ndarray:
    """C_ab from q_ab: (4,) -> (3, 3), or (N, 4) -> (N, 3, 3)."""
    batch = getattr(q, "ndim", 1) == 2
    q0, q1, q2, q3 = np.asarray(q).T if batch else q
    C = np.array(
        [
            [q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3, 2 * (q1 * q2 - q0 * q3), 2 * (q1 * q3 + q0 * q2)],
            [2 * (q1 * q2 + q0 * q3), q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3, 2 * (q2 * q3 - q0 * q1)],
            [2 * (q1 * q3 - q0 * q2), 2 * (q2 * q3 + q0 * q1), q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3],
        ]
    )
    return np.moveaxis(C, -1, 0) if batch else C


def dcm_to_quat(C) -> np.ndarray:
    """q_ab from C_ab (Shepperd's method, robust for every rotation)."""
    C = np.asarray(C, dtype=float)
    tr = C[0, 0] + C[1, 1] + C[2, 2]
    cands = np.array([tr, C[0, 0], C[1, 1], C[2, 2]])
    i = int(np.argmax(cands))
    if i == 0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q = [0.25 * s, (C[2, 1] - C[1, 2]) / s, (C[0, 2] - C[2, 0]) / s, (C[1, 0] - C[0, 1]) / s]
    elif i == 1:
        s = 2.0 * math.sqrt(1.0 + 2 * C[0, 0] - tr)
        q = [(C[2, 1] - C[1, 2]) / s, 0.25 * s, (C[0, 1] + C[1, 0]) / s, (C[0, 2] + C[2, 0]) / s]
    elif i == 2:
        s = 2.0 * math.sqrt(1.0 + 2 * C[1, 1] - tr)
        q = [(C[0, 2] - C[2, 0]) / s, (C[0, 1] + C[1, 0]) / s, 0.25 * s, (C[1, 2] + C[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + 2 * C[2, 2] - tr)
        q = [(C[1, 0] - C[0, 1]) / s, (C[0, 2] + C[2, 0]) / s, (C[1, 2] + C[2, 1]) / s, 0.25 * s]
    return quat_normalize(q)


def euler_to_dcm(euler) -> np.ndarray:
    """C_nb from ZYX Euler angles (roll, pitch, yaw) [rad]: (3,) -> (3, 3), or (N, 3) -> (N, 3, 3)."""
    r, p, y = np.asarray(euler, dtype=float).T
    xp = math if isinstance(r, float) else np
    cr, sr, cp, sp, cy, sy = xp.cos(r), xp.sin(r), xp.cos(p), xp.sin(p), xp.cos(y), xp.sin(y)
    C = np.array(
        [
            [cp * cy, -cr * sy + sr * sp * cy, sr * sy + cr * sp * cy],
            [cp * sy, cr * cy + sr * sp * sy, -sr * cy + cr * sp * sy],
            [-sp, sr * cp, cr * cp],
        ]
    )
    return np.moveaxis(C, (0, 1), (-2, -1))


def dcm_to_euler(C) -> np.ndarray:
    """ZYX Euler angles (roll, pitch, yaw) [rad] from C_nb; yaw in (-pi, pi]. (3, 3) -> (3,), or (N, 3, 3) -> (N, 3)."""
    C = np.asarray(C)
    xp = np if C.ndim == 3 else math
    pitch = xp.atan2(-C[..., 2, 0], xp.hypot(C[..., 2, 1], C[..., 2, 2]))
    roll = xp.atan2(C[..., 2, 1], C[..., 2, 2])
    yaw = xp.atan2(C[..., 1, 0], C[..., 0, 0])
    return np.stack([roll, pitch, yaw], -1) if xp is np else np.array([roll, pitch, yaw])


def euler_to_quat(euler) -> np.ndarray:
    """q_nb from ZYX Euler angles (roll, pitch, yaw) [rad]."""
    hr, hp, hy = 0.5 * euler[0], 0.5 * euler[1], 0.5 * euler[2]
    cr, sr, cp, sp, cy, sy = math.cos(hr), math.sin(hr), math.cos(hp), math.sin(hp), math.cos(hy), math.sin(hy)
    return quat_normalize(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ]
    )


def quat_to_euler(q) -> np.ndarray:
    """ZYX Euler angles (roll, pitch, yaw) [rad] from q_nb: (4,) -> (3,), or (N, 4) -> (N, 3)."""
    return dcm_to_euler(quat_to_dcm(q))


def rotvec_quat_xyz(x: float, y: float, z: float) -> tuple[float, float, float, float]:
    """Quaternion of the rotation vector (x, y, z) [rad] on Python floats (exact; series near zero)."""
    angle2 = x * x + y * y + z * z
    if angle2 < 1e-12:
        c = 1.0 - angle2 / 8.0
        s = 0.5 - angle2 / 48.0
    else:
        angle = math.sqrt(angle2)
        c = math.cos(0.5 * angle)
        s = math.sin(0.5 * angle) / angle
    return c, s * x, s * y, s * z


def rotvec_to_quat(rv) -> np.ndarray:
    """Quaternion of the rotation vector rv [rad]."""
    return np.array(rotvec_quat_xyz(*(float(v) for v in rv)))


def quat_to_rotvec(q) -> np.ndarray:
    """Rotation vector [rad] of a unit quaternion, angle in [0, pi]."""
    q = quat_normalize(q)
    v = q[1:]
    sin_half = float(np.linalg.norm(v))
    if sin_half < 1e-9:
        return 2.0 * v / q[0]
    return 2.0 * math.atan2(sin_half, q[0]) * v / sin_half


def rotvec_to_dcm(rv) -> np.ndarray:
    """DCM of the rotation vector rv [rad] (Rodrigues)."""
    return quat_to_dcm(rotvec_to_quat(rv))


def dcm_to_rotvec(C) -> np.ndarray:
    """Rotation vector [rad] of a DCM."""
    return quat_to_rotvec(dcm_to_quat(C))


def wrap_angle(a):
    """Wrap angles [rad] to (-pi, pi]."""
    return -((-np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi)
