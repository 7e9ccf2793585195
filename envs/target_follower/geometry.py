"""TargetFollower geometry: the robot's kinematic chain, the camera pose, and the image state.

World frame (PyBullet): x forward at the start, y left, z up. The robot's base frame sits
on the floor at (x, y) with yaw psi (counter-clockwise, so a positive yaw rate turns
left). The tilt axis is the base's y axis at ``TILT_AXIS_BASE_M``; the tilt angle phi is
positive when the camera looks up. The camera's optical centre lies ``delta_y_m`` (the
spec's delta y) above the tilt axis along the tilted camera's up axis, which is the spec's
appendix geometry X_c = R(phi, theta)(X_t - X_m) - (0, delta_y, 0) with theta = psi.

Image state (spec "Image-space state"), in pixels:
- x_i = u - c_x (right positive), y_i = c_y - v (up positive), with (u, v) the OpenCV
  pixel of the target's centre: the spec's x_i = -f_x x_c / z_c, y_i = f_y y_c / z_c in
  its camera axes (x left, y up, z forward);
- d_x = f_x W / z_c, the target's width in pixels at the depth z_c of its centre.

The target-induced image velocity X_i^t' = J_t V_t (spec (3)(4)) is the time derivative
of the image state when only the target moves, evaluated exactly from the camera pose.
"""

from __future__ import annotations

import math

import numpy as np

# Tilt axis in the base frame (m): 1.2 m above the midpoint of the wheel axle, on the
# robot's turning axis, as the spec's geometry has it (X_m is both the unicycle's position
# and the tilt axis's); an axis ahead of the axle would add a lateral term to B_i's omega
# column.
TILT_AXIS_BASE_M = np.array([0.0, 0.0, 1.20])
MIN_DEPTH_M = 0.05  # a target closer than this to the camera plane has no image state
_TILT_AXIS_BASE = tuple(TILT_AXIS_BASE_M.tolist())


def camera_pose(
    robot_xy_m: np.ndarray, yaw_rad: float, tilt_rad: float, delta_y_m: float
) -> np.ndarray:
    """``T_world_cam`` (OpenCV camera axes) of the robot's camera."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    ct, st = math.cos(tilt_rad), math.sin(tilt_rad)
    R_world_base = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    # OpenCV: x right, y down, z forward: the columns (0, -1, 0), minus the camera's up
    # (-st, 0, ct) and the optical axis (ct, 0, st), tilted up by phi (-up's 0 is -0.0, as
    # np.column_stack([right, -up, forward]) made it).
    R_base_cam = np.array([[0.0, st, ct], [-1.0, -0.0, 0.0], [0.0, -ct, st]])
    # TILT_AXIS_BASE_M + delta_y_m * up and the robot's offset, elementwise in floats; the
    # matrix products stay NumPy's.
    axis_x, axis_y, axis_z = _TILT_AXIS_BASE
    centre_base = np.array(
        [axis_x + delta_y_m * -st, axis_y + delta_y_m * 0.0, axis_z + delta_y_m * ct]
    )
    x, y, z = (R_world_base @ centre_base).tolist()
    r0, r1, r2 = (R_world_base @ R_base_cam).tolist()
    return np.array(  # pose_matrix(R_world_cam, centre_world)
        [
            [*r0, x + float(robot_xy_m[0])],
            [*r1, y + float(robot_xy_m[1])],
            [*r2, z + 0.0],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


def target_in_camera(T_world_cam: np.ndarray, target_pos_world: np.ndarray) -> np.ndarray:
    """The target's centre in the (OpenCV) camera frame."""
    return T_world_cam[:3, :3].T @ (np.asarray(target_pos_world, dtype=float) - T_world_cam[:3, 3])


def image_state(
    K: np.ndarray, T_world_cam: np.ndarray, target_pos_world: np.ndarray, width_m: float
) -> np.ndarray:
    """(x_i, y_i, d_x) in pixels; depth clamped at MIN_DEPTH_M (the target is then
    behind or beside the camera and the numbers only mark it as far out of view)."""
    x, y, z = target_in_camera(T_world_cam, target_pos_world).tolist()
    return np.array(image_state_in_camera(K, x, y, z, width_m))


def image_state_in_camera(
    K: np.ndarray, x_m: float, y_m: float, z_m: float, width_m: float
) -> tuple[float, float, float]:
    """:func:`image_state` of the target at (x_m, y_m, z_m) in the camera frame."""
    z = max(z_m, MIN_DEPTH_M)
    fx, fy = K[0, 0], K[1, 1]
    return fx * x_m / z, -fy * y_m / z, fx * width_m / z


def target_image_velocity(
    K: np.ndarray,
    T_world_cam: np.ndarray,
    target_pos_world: np.ndarray,
    target_vel_world: np.ndarray,
    width_m: float,
) -> np.ndarray:
    """X_i^t' = J_t V_t (spec (3)(4)): the image state's rate from the target's motion
    alone, in px/s, the exact derivative of :func:`image_state` with the camera held."""
    p = target_in_camera(T_world_cam, target_pos_world)
    pdot = T_world_cam[:3, :3].T @ np.asarray(target_vel_world, dtype=float)
    return np.array(image_velocity_in_camera(K, p.tolist(), pdot.tolist(), width_m))


def image_velocity_in_camera(
    K: np.ndarray, p_m: list[float], pdot_mps: list[float], width_m: float
) -> tuple[float, float, float]:
    """:func:`target_image_velocity` of the target at ``p_m`` moving at ``pdot_mps``
    (camera frame)."""
    (x, y, z), (vx, vy, vz) = p_m, pdot_mps
    z = max(z, MIN_DEPTH_M)
    fx, fy = K[0, 0], K[1, 1]
    return (
        fx * (vx * z - x * vz) / (z * z),
        -fy * (vy * z - y * vz) / (z * z),
        -fx * width_m * vz / (z * z),
    )


def pixel_from_image_state(K: np.ndarray, xi_px: float, yi_px: float) -> tuple[float, float]:
    """(u, v) OpenCV pixel of the image-state point (x_i, y_i)."""
    return float(xi_px + K[0, 2]), float(K[1, 2] - yi_px)


def robot_pose_from_camera(
    T_world_cam: np.ndarray, delta_y_m: float
) -> tuple[np.ndarray, float, float]:
    """(robot_xy_m, yaw_rad, tilt_rad) of the robot whose camera has pose ``T_world_cam``:
    the inverse of :func:`camera_pose`."""
    forward = T_world_cam[:3, 2]
    tilt = math.asin(max(-1.0, min(1.0, float(forward[2]))))
    yaw = math.atan2(float(forward[1]), float(forward[0]))
    ct, st = math.cos(tilt), math.sin(tilt)
    centre_base = TILT_AXIS_BASE_M + delta_y_m * np.array([-st, 0.0, ct])
    c, s = math.cos(yaw), math.sin(yaw)
    offset_xy = np.array(
        [c * centre_base[0] - s * centre_base[1], s * centre_base[0] + c * centre_base[1]]
    )
    return T_world_cam[:2, 3] - offset_xy, yaw, tilt
