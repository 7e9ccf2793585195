"""Rigid-body helpers: rotations, homogeneous transforms, and a 3-vector cross product
and a vector norm without NumPy's overhead (``np.cross`` ~50 us a call,
``np.linalg.norm`` ~2 us: too slow for a per-step hot path)."""

from __future__ import annotations

import math

import numpy as np

from observer_gym.envs.bullet import pybullet


def rot_x(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rotation_from_quaternion(quaternion_xyzw) -> np.ndarray:
    return np.array(pybullet.getMatrixFromQuaternion(quaternion_xyzw)).reshape(3, 3)


def pose_matrix(rotation: np.ndarray, translation) -> np.ndarray:
    """4x4 homogeneous transform from a 3x3 rotation and a translation."""
    T = np.eye(4)
    T[:3, :3] = rotation
    T[:3, 3] = translation
    return T


def cross3(a, b) -> np.ndarray:
    return np.array(
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    )


def norm(v: np.ndarray) -> float:
    """``float(np.linalg.norm(v))`` of a float64 array, bit for bit: the same dot product
    (BLAS) and square root, without ``norm``'s dispatch. Plain arithmetic would not do:
    BLAS sums the squares in its own order (with fused multiply-adds)."""
    x = v.ravel(order="K")
    return math.sqrt(x.dot(x))
