"""``raw``: TargetFollower's detector alone, no filter: the honest "no observer" baseline.

Per step, from the newest delivered frame
(:class:`~observer_gym.estimation.target_follower.frames.FrameReader`):

- the image state X_i = (x_i, y_i, d_x) is the last detection, held through misses (no
  prediction to the step's time, however old the frame);
- the target-induced rate X_i^t' (the layout's rate entries, spec (3)(4)) is the finite
  difference of the last two detections over their capture times t_0 < t_1, less the
  robot's part by the model (30) inverted, with B_i at the older detection and the tilt
  at its capture:

      X_i^t' = (Z_1 - Z_0) / (t_1 - t_0) - B_i(Z_0, phi(t_0)) u_mean,

  u_mean the mean of the applied velocity over [t_0, t_1]; zero until two detections;
- ``tracking_valid`` is 1 while the newest frame received had a detection (a dropped
  frame changes nothing, a frame without the target makes it 0: the detector alone does
  not know where a target it does not see is), ``target_visible`` 1 when this step's new
  frame had one.

Covariance: while valid, the detection noise R of the noise rule
(:mod:`~observer_gym.estimation.target_follower.noise`: the declared sensor's; given
``params``, their R_0) propagated through the difference: Cov(Z_1) = R_1,
Cov(rate) = (R_1 + R_0) / dt^2, Cov(Z_1, rate) = R_1 / dt (rates unknown before the
second detection: variance ``reliability_threshold``); while not valid,
``reliability_threshold`` x I, the VSE's "unknown". No innovation, so no NIS.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from observer_gym.envs.target_follower import TargetFollowerEnv
from observer_gym.estimation.observer import Estimate
from observer_gym.estimation.target_follower.detector import TargetFollowerDetector
from observer_gym.estimation.target_follower.filters import Table1Noise, VSEParams
from observer_gym.estimation.target_follower.frames import FrameReader
from observer_gym.estimation.target_follower.models import (
    TargetFollowerCameraParams,
    robot_jacobian,
)
from observer_gym.estimation.target_follower.noise import NoiseRule
from observer_gym.estimation.target_follower.state_layout import (
    RobotStep,
    lost_estimate,
    state_estimate,
)

__all__ = ["RawObserver"]


class _Detection(NamedTuple):
    """A frame's detection, as the finite difference uses it."""

    z_px: np.ndarray  # (x_i, y_i, d_x)
    capture_time_s: float
    tilt_rad: float  # the camera's tilt at capture


class RawObserver:
    """The detection held, rates by finite differences (see the module docstring).

    Args:
        env: the TargetFollower env (calibration and obs_mode).
        params: the VSE tuning whose reliability threshold (and, given, R_0) the
            covariance reports (default: the noise rule's R, Table 1's threshold).
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
        self.history_s = env.sensor_spec.history_s(env.config.dt_s)
        self.frames = FrameReader(env, detector, owner="RawObserver")
        self.reset()

    def reset(self) -> None:
        self.frames.reset()
        self._robot: RobotStep | None = None
        # (start_s, end_s, applied) of the recent steps, for the mean input between captures
        self._inputs: list[tuple[float, float, np.ndarray]] = []
        self._last: _Detection | None = None  # the last detection
        self._rate_pxps = np.zeros(3)
        self._rate_dt_s: float | None = None  # the capture interval of the last difference
        self._R = np.zeros((3, 3))  # R of the last detection
        self._rate_cov = np.zeros((3, 3))  # Cov of the last difference's rate
        self._valid = False

    def _mean_input(self, start_s: float, end_s: float) -> np.ndarray:
        """The mean of the applied velocity over [start_s, end_s] (zero where unknown)."""
        total = np.zeros(3)
        for a, b, applied in self._inputs:
            overlap_s = min(b, end_s) - max(a, start_s)
            if overlap_s > 0.0:
                total += overlap_s * applied
        return total / (end_s - start_s)

    def observe(self, obs: Any, info: dict, action: np.ndarray | None) -> Estimate:
        robot = RobotStep.from_info(info, action, self.delta_y_m)
        if action is None or self._robot is None:
            self.reset()
        else:
            self._inputs.append((self._robot.time_s, robot.time_s, robot.applied))
        self._robot = robot
        frame = self.frames.newest(obs, info)
        if frame is not None:
            self._valid = frame.z_px is not None
        if frame is not None and frame.z_px is not None:
            detection = _Detection(frame.z_px, frame.capture_time_s, frame.tilt_rad)
            R_last, self._R = self._R, self.noise.R(detection.z_px)
            last = self._last
            if last is not None:
                dt_s = detection.capture_time_s - last.capture_time_s
                B_i = robot_jacobian(last.z_px, last.tilt_rad, self.camera_params)
                u_mean = self._mean_input(last.capture_time_s, detection.capture_time_s)
                # X_i^t' = (Z_1 - Z_0) / dt - B_i(Z_0, phi(t_0)) u_mean   (30) inverted
                self._rate_pxps = (detection.z_px - last.z_px) / dt_s - B_i.dot(u_mean)
                self._rate_dt_s = dt_s
                self._rate_cov = (self._R + R_last) / dt_s**2
            self._last = detection
        oldest_s = robot.time_s - self.history_s
        if self._last is not None:
            oldest_s = min(oldest_s, self._last.capture_time_s)
        self._inputs = [i for i in self._inputs if i[1] > oldest_s]
        visible = frame is not None and frame.z_px is not None
        held = self._last if self._valid else None  # valid: the newest frame's detection
        if held is not None:
            cov = self.params.reliability_threshold * np.eye(6)  # rates unknown until a difference
            cov[:3, :3] = self._R
            if self._rate_dt_s is not None:
                cov[3:, 3:] = self._rate_cov  # Var(Z_1 - Z_0) / dt^2
                cov[:3, 3:] = cov[3:, :3] = self._R / self._rate_dt_s  # Cov(Z_1, (Z_1 - Z_0) / dt)
            mean, cov = state_estimate(held.z_px, self._rate_pxps, cov, robot, True, visible)
        else:
            image = np.zeros(3) if self._last is None else self._last.z_px
            mean, cov = lost_estimate(image, self.params.reliability_threshold, robot, visible)
        z = None if frame is None else frame.z_px
        return Estimate(mean, cov, visible, z, robot.time_s)
