"""The pinhole camera between the target's world position and TargetFollower's image
state, with its Jacobians: the measurement model of the pixel EKF
(:mod:`~observer_gym.estimation.target_follower.pixel_ekf`).

The target's centre p_w (world, m) moving at v_w (m/s) is seen by a camera at
``T_world_cam`` (OpenCV axes: x right, y down, z forward) as
p_c = (X, Y, Z) = R^T (p_w - t), and its image state (envs/target_follower/geometry.py) is

    x_i = f_x X / Z,   y_i = -f_y Y / Z,   d_x = f_x W / Z                    (pinhole)

(x_i right and y_i up from the principal point, W the target's width). With the camera
held, the target's motion moves it at p_c' = R^T v_w, so its target-induced image rate
X_i^t' = J_t V_t (spec (3)(4)) is the time derivative

    x_i' = f_x (X' Z - X Z') / Z^2,  y_i' = -f_y (Y' Z - Y Z') / Z^2,  d_x' = -f_x W Z' / Z^2.

Jacobians are analytic (tests/estimation/test_target_follower_observers.py checks them
against central differences).
"""

from __future__ import annotations

import numpy as np

__all__ = ["back_project", "image_state_and_rate", "project"]


def _camera_point(T_world_cam: np.ndarray, p_world_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(p_c, R^T): the point in the camera frame and the world-to-camera rotation."""
    R_cam_world = T_world_cam[:3, :3].T
    return R_cam_world.dot(p_world_m - T_world_cam[:3, 3]), R_cam_world


def project(
    p_world_m: np.ndarray, T_world_cam: np.ndarray, fx_px: float, fy_px: float, width_m: float
) -> tuple[np.ndarray, np.ndarray, float]:
    """(h, H, Z): the image state (x_i, y_i, d_x) of a target at ``p_world_m``, its
    Jacobian (3, 3) with respect to p_w, and the depth Z (m; the caller checks Z > 0)."""
    (X, Y, Z), R_cw = _camera_point(T_world_cam, p_world_m)
    inv_z = 1.0 / Z
    # x_i = f_x X / Z, y_i = -f_y Y / Z, d_x = f_x W / Z
    h = np.array([fx_px * X * inv_z, -fy_px * Y * inv_z, fx_px * width_m * inv_z])
    # d h / d p_c, then d p_c / d p_w = R^T
    dh_dpc = np.array(
        [
            [fx_px * inv_z, 0.0, -fx_px * X * inv_z * inv_z],
            [0.0, -fy_px * inv_z, fy_px * Y * inv_z * inv_z],
            [0.0, 0.0, -fx_px * width_m * inv_z * inv_z],
        ]
    )
    return h, dh_dpc.dot(R_cw), float(Z)


def image_state_and_rate(
    x: np.ndarray, T_world_cam: np.ndarray, fx_px: float, fy_px: float, width_m: float
) -> tuple[np.ndarray, np.ndarray, float]:
    """(s, J, Z): s = (x_i, y_i, d_x, x_i', y_i', d_x') (6,) of the target state
    x = (p_w, v_w), its Jacobian J (6, 6) with respect to x, and the depth Z."""
    (X, Y, Z), R_cw = _camera_point(T_world_cam, x[:3])
    Xd, Yd, Zd = R_cw.dot(x[3:])
    iz = 1.0 / Z
    iz2 = iz * iz
    iz3 = iz2 * iz
    fx, fy, W = fx_px, fy_px, width_m
    s = np.array(
        [
            fx * X * iz,
            -fy * Y * iz,
            fx * W * iz,
            fx * (Xd * Z - X * Zd) * iz2,  # x_i' = f_x (X' Z - X Z') / Z^2
            -fy * (Yd * Z - Y * Zd) * iz2,  # y_i' = -f_y (Y' Z - Y Z') / Z^2
            -fx * W * Zd * iz2,  # d_x' = -f_x W Z' / Z^2
        ]
    )
    # d s / d p_c (6, 3) and d s / d p_c' (6, 3); p_c = R^T (p_w - t), p_c' = R^T v_w
    ds_dp = np.array(
        [
            [fx * iz, 0.0, -fx * X * iz2],
            [0.0, -fy * iz, fy * Y * iz2],
            [0.0, 0.0, -fx * W * iz2],
            [-fx * Zd * iz2, 0.0, -fx * Xd * iz2 + 2.0 * fx * X * Zd * iz3],
            [0.0, fy * Zd * iz2, fy * Yd * iz2 - 2.0 * fy * Y * Zd * iz3],
            [0.0, 0.0, 2.0 * fx * W * Zd * iz3],
        ]
    )
    ds_dv = np.array(
        [
            [0.0, 0.0, 0.0],
            [0.0, 0.0, 0.0],
            [0.0, 0.0, 0.0],
            [fx * iz, 0.0, -fx * X * iz2],
            [0.0, -fy * iz, fy * Y * iz2],
            [0.0, 0.0, -fx * W * iz2],
        ]
    )
    J = np.hstack([ds_dp.dot(R_cw), ds_dv.dot(R_cw)])
    return s, J, float(Z)


def back_project(
    z_px: np.ndarray, T_world_cam: np.ndarray, fx_px: float, fy_px: float, width_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """(p_w, G): the world position whose image state is ``z_px`` = (x_i, y_i, d_x) (the
    pinhole model inverted: Z = f_x W / d_x, X = x_i Z / f_x, Y = -y_i Z / f_y) and its
    Jacobian G (3, 3) with respect to z. ``d_x`` must be > 0."""
    x_i, y_i, d_x = (float(v) for v in z_px)
    Z = fx_px * width_m / d_x  # d_x = f_x W / Z
    p_c = np.array([x_i * Z / fx_px, -y_i * Z / fy_px, Z])
    dZ_dd = -Z / d_x
    dpc_dz = np.array(
        [
            [Z / fx_px, 0.0, x_i * dZ_dd / fx_px],
            [0.0, -Z / fy_px, -y_i * dZ_dd / fy_px],
            [0.0, 0.0, dZ_dd],
        ]
    )
    R_world_cam = T_world_cam[:3, :3]
    return R_world_cam.dot(p_c) + T_world_cam[:3, 3], R_world_cam.dot(dpc_dz)
