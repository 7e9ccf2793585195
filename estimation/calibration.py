"""The declared calibration uncertainty as a covariance: how far a quantity computed from
pixels through the nominal camera (``K``, ``T_world_cam``) may be off because the real
camera differs from it by the sizes ``SensorSpec`` declares.

The env draws each camera's error once per episode (envs/camera_rig.py): its pose rotated
by ``calib_rotation_error_deg`` about a uniform direction and moved by
``calib_translation_error_m`` in a uniform direction (in the nominal camera's frame), its
focal lengths scaled by 1 +- ``calib_focal_error``, its principal point moved by
``calib_principal_point_error_px`` in a uniform direction. As random variables of those
sizes: a rotation vector of per-axis variance s^2 / 3, a translation of t^2 / 3 per axis,
a focal scale of variance e_f^2 and a principal-point offset of p^2 / 2 per axis. For a
function y = f(K, T_world_cam) of the calibration, to first order

    Sigma_y = sum_i var_i (df / dc_i)(df / dc_i)^T

over those nine parameters c_i (central differences: the functions are OpenCV's PnP and
the like, which give no derivatives). The error is one constant offset per episode, which
no innovation sees: observers add Sigma_y to the covariance they report, not to R.
:func:`calibration_jacobian` gives the columns df / dc_i and their variances themselves,
for a filter that carries the calibration error as consider parameters (BallCatcher's,
estimation/ball_catcher/calibration_consider.py).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from observer_gym.envs.sensor import SensorSpec

__all__ = [
    "calibration_covariance",
    "calibration_jacobian",
    "calibration_variances",
    "moved_camera",
]

_STEPS = {"rotation": 1e-4, "translation": 1e-4, "focal": 1e-4, "principal_point": 0.01}


def calibration_variances(sensor: SensorSpec) -> dict[str, float]:
    """Per-parameter variances of the declared calibration error (see the module
    docstring); only the kinds with a non-zero size."""
    out = {
        "rotation": math.radians(sensor.calib_rotation_error_deg) ** 2 / 3.0,
        "translation": sensor.calib_translation_error_m**2 / 3.0,
        "focal": sensor.calib_focal_error**2,
        "principal_point": sensor.calib_principal_point_error_px**2 / 2.0,
    }
    return {kind: var for kind, var in out.items() if var > 0.0}


def _rotation(axis: int, angle_rad: float) -> np.ndarray:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.eye(3)
    R[i, i] = R[j, j] = c
    R[i, j], R[j, i] = -s, s
    return R


def _perturbed(kind: str, index: int, step: float, K: np.ndarray, T: np.ndarray):
    """(K, T_world_cam) of the camera moved by ``step`` along one calibration parameter."""
    K, T = K.copy(), T.copy()
    if kind == "rotation":  # about the camera's own axis ``index``
        T[:3, :3] = T[:3, :3] @ _rotation(index, step)
    elif kind == "translation":
        T[:3, 3] = T[:3, 3] + T[:3, :3][:, index] * step
    elif kind == "focal":
        K[0, 0] *= 1.0 + step
        K[1, 1] *= 1.0 + step
    else:  # principal point, axis ``index``
        K[index, 2] += step
    return K, T


_AXES = {"rotation": 3, "translation": 3, "focal": 1, "principal_point": 2}


def calibration_jacobian(
    f: Callable[[np.ndarray, np.ndarray], np.ndarray | None],
    K: np.ndarray,
    T_world_cam: np.ndarray,
    variances: dict[str, float],
) -> tuple[np.ndarray, np.ndarray] | None:
    """(J (len(y), m), var (m,)): the columns df / dc_i of ``f(K, T_world_cam)`` along the
    m calibration parameters of ``variances`` (:func:`calibration_variances`; each kind's
    axes in order: rotation about the camera's x, y, z, translation along them, focal
    scale, principal point u, v), by central differences, and each parameter's variance.
    None if ``f`` gives None beside the nominal camera, or nothing is uncertain."""
    if not variances:
        return None
    K, T = np.asarray(K, dtype=float), np.asarray(T_world_cam, dtype=float)
    columns, var = [], []
    for kind, kind_var in variances.items():
        h = _STEPS[kind]
        for index in range(_AXES[kind]):
            ahead = f(*_perturbed(kind, index, h, K, T))
            behind = f(*_perturbed(kind, index, -h, K, T))
            if ahead is None or behind is None:
                return None
            # df/dc_i = (f(c + h) - f(c - h)) / 2h
            columns.append((np.asarray(ahead, float) - np.asarray(behind, float)) / (2.0 * h))
            var.append(kind_var)
    return np.stack(columns, axis=-1), np.array(var)


def moved_camera(
    K: np.ndarray, T_world_cam: np.ndarray, variances: dict[str, float], c: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(K, T_world_cam) of the camera moved by ``c`` (m,) along the calibration parameters
    of ``variances``, in :func:`calibration_jacobian`'s order and units (rad, m, focal
    scale, px): the camera a filter's estimated parameters describe. The moves are
    applied one after another (rotation about the camera's x, then y, then z, ...), which
    agrees with the parameters' first-order model for small ``c``."""
    K, T = np.array(K, dtype=float), np.array(T_world_cam, dtype=float)
    c = np.asarray(c, dtype=float).reshape(-1)
    expected = sum(_AXES[kind] for kind in variances)
    if c.shape != (expected,):
        raise ValueError(f"moved_camera: c has shape {c.shape}, expected ({expected},)")
    i = 0
    for kind in variances:
        for index in range(_AXES[kind]):
            K, T = _perturbed(kind, index, float(c[i]), K, T)
            i += 1
    return K, T


def calibration_covariance(
    f: Callable[[np.ndarray, np.ndarray], np.ndarray | None],
    K: np.ndarray,
    T_world_cam: np.ndarray,
    variances: dict[str, float],
) -> np.ndarray | None:
    """Sigma_y of ``f(K, T_world_cam)`` under the calibration ``variances``
    (:func:`calibration_variances`); None if ``f`` gives None beside the nominal camera.
    A zero matrix of y's size when nothing is uncertain is left to the caller: with no
    variances this returns None."""
    jacobian = calibration_jacobian(f, K, T_world_cam, variances)
    if jacobian is None:
        return None
    J, var = jacobian
    sigma = None
    for i in range(len(var)):
        # Sigma_y = sum_i var_i (df/dc_i)(df/dc_i)^T
        term = var[i] * np.outer(J[..., i], J[..., i])
        sigma = term if sigma is None else sigma + term
    return sigma
