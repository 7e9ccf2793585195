"""``oracle-visible``: the true image state whenever the target is detected, the VSE's
model prediction otherwise. It READS GROUND TRUTH (``info["state"]``) and is for
analysis only: it tells the cost of occlusion (what even a perfect filter loses while the
target is hidden) apart from the cost of filtering (what a filter loses on top).

Per step:

- when this step's new frame gave a detection (the same detection the other observers
  use: the orange-blob detector on an rgb frame, the perfect detector's report in
  measurements mode; :class:`~observer_gym.estimation.target_follower.frames.FrameReader`),
  the image state and its target-induced rate are the truth's, ``info["state"]``, at the
  step's time (so a late frame costs nothing here: latency is not what it measures);
- otherwise they are predicted from the last such step by the VSE's model (30), the
  target's image rate held and the robot's motion through B_i at the predicted image
  state and the tilt at the start of each step (spec (28)-(31)):

      X_i <- X_i + T X_i^t' + T B_i u,   X_i^t' <- X_i^t';

- ``tracking_valid`` is the truth's (the target is in front of the camera) from the
  first detection on (0 before it), ``target_visible`` whether this step's new frame gave
  a detection.

Covariance: 0 on detected steps (the truth); while predicting, the VSE's model
uncertainty from 0 at the last detected step, P <- F P F^T + Q with the noise rule's Q
(:mod:`~observer_gym.estimation.target_follower.noise`: the target's motion model; given
``params``, spec Table 1's Q_0).
Before the first detection the estimate is all zeros with covariance
``reliability_threshold`` x I. No innovation, so no NIS.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from observer_gym.envs.target_follower import IMAGE, IMAGE_RATE, StateIndex, TargetFollowerEnv
from observer_gym.estimation.observer import Estimate
from observer_gym.estimation.target_follower.detector import TargetFollowerDetector
from observer_gym.estimation.target_follower.filters import Table1Noise, VSEParams
from observer_gym.estimation.target_follower.frames import FrameReader
from observer_gym.estimation.target_follower.models import (
    TargetFollowerCameraParams,
    image_state_transition,
    robot_jacobian,
)
from observer_gym.estimation.target_follower.noise import NoiseRule
from observer_gym.estimation.target_follower.state_layout import RobotStep, state_estimate

__all__ = ["OracleVisibleObserver"]


class OracleVisibleObserver:
    """Ground truth while detected, predicted otherwise (see the module docstring; for
    analysis only).

    Args:
        env: the TargetFollower env (calibration and obs_mode).
        params: the VSE tuning whose reliability threshold (and, given, Q_0) the
            covariance uses (default: the noise rule's Q, Table 1's threshold).
        camera_params: the f_x, f_y, W, delta_y that B_i uses (default: the calibration).
        detector: the rgb detector.
    """

    def __init__(
        self,
        env: TargetFollowerEnv,
        params: VSEParams | None = None,
        camera_params: TargetFollowerCameraParams | None = None,
        detector: TargetFollowerDetector | None = None,
    ) -> None:
        self.noise = NoiseRule.for_env(env) if params is None else Table1Noise(params)
        self.params = params or VSEParams()
        self.camera_params = camera_params or TargetFollowerCameraParams.from_calibration(
            env.calibration
        )
        self.delta_y_m = env.calibration["delta_y_m"]
        self.frames = FrameReader(env, detector, owner="OracleVisibleObserver")
        self.reset()

    def reset(self) -> None:
        self.frames.reset()
        self._robot: RobotStep | None = None
        self._x: np.ndarray | None = None  # (X_i, X_i^t'), 6
        self._P = self.params.reliability_threshold * np.eye(6)

    def observe(self, obs: Any, info: dict, action: np.ndarray | None) -> Estimate:
        robot = RobotStep.from_info(info, action, self.delta_y_m)
        if action is None or self._robot is None:
            self.reset()
        elif self._x is not None:  # predict over the step by (30)
            dt_s = round(robot.time_s - self._robot.time_s, 9)
            tilt_rad, u = self._robot.tilt_rad, robot.applied
            B_i = robot_jacobian(self._x[:3], tilt_rad, self.camera_params)
            F, G = image_state_transition(dt_s, B_i)
            Q = self.noise.image_Q(self._x[:3], tilt_rad, dt_s, u, B_i.dot(u))
            # X <- F X + G u,  P <- F P F^T + Q
            self._x = F.dot(self._x) + G.dot(u)
            self._P = F.dot(self._P).dot(F.T) + Q
        self._robot = robot
        frame = self.frames.newest(obs, info)
        visible = frame is not None and frame.z_px is not None
        truth = np.asarray(info["state"], dtype=float)
        if visible:
            self._x = np.concatenate([truth[IMAGE], truth[IMAGE_RATE]])
            self._P = np.zeros((6, 6))
        # the truth's flag, once there is something to hold
        valid = self._x is not None and bool(truth[StateIndex.TRACKING_VALID] >= 0.5)
        x = np.zeros(6) if self._x is None else self._x
        mean, cov = state_estimate(x[:3], x[3:], self._P, robot, valid, visible)
        z = None if frame is None else frame.z_px
        return Estimate(mean, cov, visible, z, robot.time_s)
