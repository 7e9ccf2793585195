"""A TargetFollower observer's output in the env's state layout
(envs/target_follower/layout.py), filled the same way by every observer of this package.

- image state and target-induced rates (and their 6x6 covariance) from the observer;
- the robot's pose (x, y, yaw) and the tilt from the step's ``info["camera"]
  ["T_world_cam"]`` (envs/target_follower/geometry.robot_pose_from_camera: the wheel
  odometry and tilt encoder, exact in this kinematic simulation; their covariance 0);
- the velocity applied over the last step, ``info["applied_action"]`` (zeros after a
  reset);
- ``tracking_valid`` and ``target_visible`` as the observer says.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from observer_gym.envs.target_follower import APPLIED, IMAGE, IMAGE_RATE, STATE_DIM, StateIndex
from observer_gym.envs.target_follower.geometry import robot_pose_from_camera

__all__ = ["RobotStep", "lost_estimate", "state_estimate"]


@dataclass(frozen=True)
class RobotStep:
    """What the robot reports at a step: its pose then and the velocity it applied over
    the step."""

    time_s: float
    robot_xy_m: np.ndarray
    yaw_rad: float
    tilt_rad: float
    applied: np.ndarray  # (v, omega, omega_t) over the step that ends at time_s

    @classmethod
    def from_info(cls, info: dict, action: np.ndarray | None, delta_y_m: float) -> RobotStep:
        """From a step's (or reset's) ``info``; ``action`` stands in for a missing
        ``info["applied_action"]`` (zeros if both are missing)."""
        xy, yaw, tilt = robot_pose_from_camera(info["camera"]["T_world_cam"], delta_y_m)
        applied = info.get("applied_action")
        if applied is None:
            applied = np.zeros(3) if action is None else action
        return cls(float(info["time_s"]), xy, yaw, tilt, np.asarray(applied, dtype=float))


def state_estimate(
    image_px: np.ndarray,
    rate_pxps: np.ndarray,
    image_cov: np.ndarray,
    robot: RobotStep,
    valid: bool,
    visible: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """(mean, covariance) in the state layout: the image state (3,) and its
    target-induced rate (3,) with their covariance ``image_cov`` (6, 6), the robot's
    step, ``tracking_valid`` = ``valid``, ``target_visible`` = ``visible``."""
    mean = np.zeros(STATE_DIM)
    cov = np.zeros((STATE_DIM, STATE_DIM))
    mean[IMAGE] = image_px
    mean[IMAGE_RATE] = rate_pxps
    cov[:6, :6] = image_cov
    mean[StateIndex.ROBOT_X : StateIndex.ROBOT_Y + 1] = robot.robot_xy_m
    mean[StateIndex.ROBOT_YAW] = robot.yaw_rad
    mean[StateIndex.TILT] = robot.tilt_rad
    mean[APPLIED] = robot.applied
    mean[StateIndex.TRACKING_VALID] = float(valid)
    mean[StateIndex.TARGET_VISIBLE] = float(visible)
    return mean, cov


def lost_estimate(
    last_image_px: np.ndarray, reliability_threshold: float, robot: RobotStep, visible: bool
) -> tuple[np.ndarray, np.ndarray]:
    """(mean, covariance) while tracking is not reliable: the last reliable image state,
    zero rates, covariance ``reliability_threshold`` x I, ``tracking_valid`` False
    (:func:`state_estimate`)."""
    unknown = reliability_threshold * np.eye(6)
    return state_estimate(last_image_px, np.zeros(3), unknown, robot, False, visible)
