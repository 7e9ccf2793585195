"""Observation layouts of TargetFollower-v0, defined once and exported.

``obs_mode="state"`` (and ``info["state"]``, and an observer's estimate) is a float vector
with the entries STATE_NAMES, indexed by :class:`StateIndex`:

- the image state X_i = (x_i, y_i, d_x) in pixels (envs/target_follower/geometry.py:
  x_i right and y_i up from the principal point, d_x = f_x W / z_c);
- the target-induced image velocity X_i^t' = J_t V_t in px/s (spec (3)(4));
- the robot's pose (x, y, yaw) on the floor and the camera's tilt phi (its wheel odometry
  and tilt encoder, exact in this kinematic simulation);
- the velocity (v, omega, omega_t) applied over the last step (after the drive's scaling
  and quantisation), the u of the spec's estimator (30);
- ``tracking_valid``: 1 when the image state is defined (ground truth: the target is in
  front of the camera; an observer: its estimate is reliable), else 0;
- ``target_visible``: 1 when the camera sees the target (ground truth: its centre is on
  the image and it is not fully hidden; an observer: it was detected in this step's
  frame), else 0.

``obs_mode="measurements"`` is a Dict: TARGET_PX, the detected (x_i, y_i, d_x) under the
spec's noise model, and DETECTED.
"""

from __future__ import annotations

from enum import IntEnum

STATE_NAMES = (
    "x_i_px",
    "y_i_px",
    "d_x_px",
    "x_i_target_rate_pxps",
    "y_i_target_rate_pxps",
    "d_x_target_rate_pxps",
    "robot_x_m",
    "robot_y_m",
    "robot_yaw_rad",
    "tilt_rad",
    "applied_speed_mps",
    "applied_yaw_rate_radps",
    "applied_tilt_rate_radps",
    "tracking_valid",
    "target_visible",
)


class StateIndex(IntEnum):
    X_I = 0
    Y_I = 1
    D_X = 2
    X_I_RATE = 3
    Y_I_RATE = 4
    D_X_RATE = 5
    ROBOT_X = 6
    ROBOT_Y = 7
    ROBOT_YAW = 8
    TILT = 9
    SPEED = 10
    YAW_RATE = 11
    TILT_RATE = 12
    TRACKING_VALID = 13
    TARGET_VISIBLE = 14


STATE_DIM = len(STATE_NAMES)
IMAGE = slice(StateIndex.X_I, StateIndex.D_X + 1)  # X_i
IMAGE_RATE = slice(StateIndex.X_I_RATE, StateIndex.D_X_RATE + 1)  # X_i^t'
ROBOT_POSE = slice(StateIndex.ROBOT_X, StateIndex.ROBOT_YAW + 1)
APPLIED = slice(StateIndex.SPEED, StateIndex.TILT_RATE + 1)  # u = (v, omega, omega_t)

# Bounds of the state observation (the env clips the observation to them; info["state"]
# is never clipped). Image entries are bounded well beyond the image: a target outside it
# ends the episode after lost_timeout_s.
STATE_HIGH = (
    5000.0,
    5000.0,
    5000.0,
    1e5,
    1e5,
    1e5,
    1e4,
    1e4,
    1e4,
    3.2,
    10.0,
    10.0,
    10.0,
    1.0,
    1.0,
)
STATE_LOW = (*(-h for h in STATE_HIGH[:-2]), 0.0, 0.0)

# Measurement keys.
TARGET_PX = "target_px"  # (3,): x_i, y_i, d_x in pixels (zeros when not detected)
DETECTED = "detected"  # (1,) MultiBinary: the target was found in the frame
