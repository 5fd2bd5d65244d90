"""Rigid transforms as 4x4 homogeneous matrices.

One convention throughout monodock: ``a_T_b`` is the pose of frame *b* in frame *a*; it maps
points expressed in *b* into *a* (``p_a = a_T_b @ p_b``). Rotations follow the URDF convention
``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "LINK_R_OPTICAL",
    "apply",
    "invert",
    "planar",
    "quaternion_from_matrix",
    "rotation_from_rpy",
    "rpy_from_rotation",
    "transform",
    "yaw_of",
]

# REP 103: an optical frame (z forward, x right, y down) inside its body frame (x forward, y left, z up).
LINK_R_OPTICAL: NDArray[np.float64] = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]], dtype=np.float64)


def rotation_from_rpy(roll: float, pitch: float, yaw: float) -> NDArray[np.float64]:
    """Rotation matrix, shape (3, 3), of URDF roll/pitch/yaw in radians (Rz @ Ry @ Rx)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ],
        dtype=np.float64,
    )


def rpy_from_rotation(R: ArrayLike) -> tuple[float, float, float]:
    """URDF (roll, pitch, yaw) in radians of a rotation matrix, shape (3, 3)."""
    m = np.asarray(R, dtype=np.float64)
    pitch = math.atan2(-m[2, 0], math.hypot(m[0, 0], m[1, 0]))
    roll = math.atan2(m[2, 1], m[2, 2])
    yaw = math.atan2(m[1, 0], m[0, 0])
    return roll, pitch, yaw


def transform(R: ArrayLike, t: ArrayLike) -> NDArray[np.float64]:
    """Homogeneous 4x4 matrix from a rotation, shape (3, 3), and a translation, shape (3,)."""
    T = np.eye(4)
    T[:3, :3] = np.asarray(R, dtype=np.float64)
    T[:3, 3] = np.asarray(t, dtype=np.float64).reshape(3)
    return T


def planar(x: float, y: float, yaw: float) -> NDArray[np.float64]:
    """4x4 transform of a pose on the floor: translation (x, y, 0) and a rotation about z."""
    return transform(rotation_from_rpy(0.0, 0.0, yaw), (x, y, 0.0))


def invert(T: ArrayLike) -> NDArray[np.float64]:
    """Inverse of a rigid 4x4 transform (b_T_a from a_T_b)."""
    m = np.asarray(T, dtype=np.float64)
    R = m[:3, :3]
    return transform(R.T, -R.T @ m[:3, 3])


def apply(T: ArrayLike, points: ArrayLike) -> NDArray[np.float64]:
    """Map points, shape (N, 3) or (3,), through a 4x4 transform."""
    m = np.asarray(T, dtype=np.float64)
    p = np.asarray(points, dtype=np.float64)
    return p @ m[:3, :3].T + m[:3, 3]


def yaw_of(T: ArrayLike) -> float:
    """Heading (rotation about z, radians) of the x axis of a 4x4 transform."""
    m = np.asarray(T, dtype=np.float64)
    return math.atan2(m[1, 0], m[0, 0])


def quaternion_from_matrix(R: ArrayLike) -> tuple[float, float, float, float]:
    """Unit quaternion (x, y, z, w), w >= 0, of a rotation matrix, shape (3, 3)."""
    m = np.asarray(R, dtype=np.float64)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    # Shepperd's method: divide by the largest of the four candidates, for accuracy near 180 degrees.
    if trace > max(m[0, 0], m[1, 1], m[2, 2]):
        s = 2.0 * math.sqrt(1.0 + trace)
        q = (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4.0
    elif m[0, 0] >= m[1, 1] and m[0, 0] >= m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = s / 4.0, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s
    elif m[1, 1] >= m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = (m[0, 1] + m[1, 0]) / s, s / 4.0, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, s / 4.0, (m[1, 0] - m[0, 1]) / s
    v = np.array(q, dtype=np.float64)
    v /= np.linalg.norm(v)
    if v[3] < 0:
        v = -v
    return float(v[0]), float(v[1]), float(v[2]), float(v[3])
