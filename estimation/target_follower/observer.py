"""The TargetFollower observer: detector + the visual state estimator (docs/spec/follower.md).

Per step:
1. The detection: in ``obs_mode="rgb"`` the orange-blob detector
   (:class:`~observer_gym.estimation.target_follower.detector.TargetFollowerDetector`) on
   the frame, in ``"measurements"`` the perfect detector's (x_i, y_i, d_x); none when the frame was
   dropped or the target not found.
2. The robot's proprioception: its pose and tilt from the frame's calibration
   ``T_world_cam`` (envs/target_follower/geometry.robot_pose_from_camera) and the velocity
   applied over the last step (``info["applied_action"]``: after the drive's scaling and
   quantisation, spec "the previous applied u feeds the estimator").
3. The estimator (:class:`~observer_gym.estimation.target_follower.filters.VisualStateEstimator`):
   the self-tuning KF by default (``filter="stkf"``) or the conventional KF
   (``filter="kf"``), predicting with B_i at the previous estimate and tilt (30).
The output has the env's state layout; ``tracking_valid`` is 1 while the estimate is
reliable (initialised, every diagonal element of P below the threshold), else 0, and the
image entries then hold the last reliable estimate with zero rates; ``target_visible`` is
1 when this step's frame gave a detection. A detection with a non-finite entry (NaN,
inf) is no detection (the estimator's missed-measurement step).

Frames (``obs_mode="rgb"``) must be uint8 images of the env's size (``image_size_px`` of
the frame, else the env config's), H x W x 3: others raise ``ValueError``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from observer_gym.envs.target_follower import (
    APPLIED,
    DETECTED,
    IMAGE,
    IMAGE_RATE,
    STATE_DIM,
    TARGET_PX,
    StateIndex,
    TargetFollowerEnv,
)
from observer_gym.envs.target_follower.geometry import robot_pose_from_camera
from observer_gym.estimation.observer import Estimate, checked_measurement, checked_rgb_frame
from observer_gym.estimation.target_follower.detector import TargetFollowerDetector
from observer_gym.estimation.target_follower.filters import VisualStateEstimator, VSEParams
from observer_gym.estimation.target_follower.models import (
    TargetFollowerCameraParams,
    robot_jacobian,
)

FILTERS = ("stkf", "kf")


class TargetFollowerObserver:
    """The default observer pipeline for TargetFollower-v0 (see the module docstring).

    Args:
        env: the TargetFollower env (its calibration and obs_mode are read).
        filter: "stkf" (self-tuning R, the default) or "kf" (R = R_0).
        params: the estimator's tuning (default: spec Table 1, k = 10); its
            ``self_tuning`` is set from ``filter``.
        camera_params: the f_x, f_y, W, delta_y that B_i uses (default: the env's
            calibration; the Table 2 study passes perturbed ones).
        detector: the rgb detector.
    """

    def __init__(
        self,
        env: TargetFollowerEnv,
        filter: str = "stkf",
        params: VSEParams | None = None,
        camera_params: TargetFollowerCameraParams | None = None,
        detector: TargetFollowerDetector | None = None,
    ) -> None:
        if filter not in FILTERS:
            raise ValueError(f"filter={filter!r} is not allowed; choose one of {list(FILTERS)}")
        self.filter = filter
        base = params or VSEParams()
        self.params = VSEParams(**{**base.__dict__, "self_tuning": filter == "stkf"})
        self.camera_params = camera_params or TargetFollowerCameraParams.from_calibration(
            env.calibration
        )
        self.delta_y_m = env.calibration["delta_y_m"]
        self.detector = detector or TargetFollowerDetector()
        self.from_pixels = env.config.obs_mode == "rgb"
        self.measurement_space = env.observation_space  # measurements mode: its Dict
        self.image_size_px = (int(env.config.image_width_px), int(env.config.image_height_px))
        self.vse = VisualStateEstimator(self.params)
        self.reset()

    def reset(self) -> None:
        self.vse.reset()
        self._time_s: float | None = None
        self._tilt_rad = 0.0
        self._last_image = np.zeros(3)

    def detect(self, obs: Any, frame: dict) -> np.ndarray | None:
        """(x_i, y_i, d_x) of one frame, or None (also when an entry is NaN or inf)."""
        if self.from_pixels:
            image = checked_rgb_frame(
                obs, frame.get("image_size_px", self.image_size_px), "TargetFollowerObserver"
            )
            z = self.detector.detect(image, frame["K"])
        else:
            obs = checked_measurement("TargetFollowerObserver", obs, self.measurement_space)
            if not obs[DETECTED][0]:
                return None
            z = obs[TARGET_PX]
        if z is None:
            return None
        z = np.asarray(z, dtype=float)
        return z if bool(np.all(np.isfinite(z))) else None

    def observe(self, obs: Any, info: dict, action: np.ndarray | None) -> Estimate:
        frames = info["frames"]
        z = self.detect(obs, frames[0]) if frames else None
        time_s = float(info["time_s"])
        xy, yaw, tilt = robot_pose_from_camera(info["camera"]["T_world_cam"], self.delta_y_m)
        applied = info.get("applied_action")
        if applied is None:
            applied = np.zeros(3) if action is None else action
        applied = np.asarray(applied, dtype=float)
        vse = self.vse
        if action is None or self._time_s is None:  # after a reset
            vse.reset()
            used = vse.step(z, np.zeros((3, 3)), np.zeros(3), 1.0)
        else:
            dt_s = round(time_s - self._time_s, 9)
            B_i = (
                robot_jacobian(vse.x[:3], self._tilt_rad, self.camera_params)
                if vse.initialised
                else np.zeros((3, 3))
            )
            used = vse.step(z, B_i, applied, dt_s)
        self._time_s = time_s
        self._tilt_rad = tilt
        mean = np.zeros(STATE_DIM)
        cov = np.zeros((STATE_DIM, STATE_DIM))
        valid = vse.initialised
        if valid:
            self._last_image = vse.x[:3].copy()
            mean[IMAGE] = vse.x[:3]
            mean[IMAGE_RATE] = vse.x[3:]
            cov[:6, :6] = vse.P
        else:
            mean[IMAGE] = self._last_image
            cov[:6, :6] = np.eye(6) * self.params.reliability_threshold
        mean[StateIndex.ROBOT_X : StateIndex.ROBOT_Y + 1] = xy
        mean[StateIndex.ROBOT_YAW] = yaw
        mean[StateIndex.TILT] = tilt
        mean[APPLIED] = applied
        mean[StateIndex.TRACKING_VALID] = float(valid)
        mean[StateIndex.TARGET_VISIBLE] = float(z is not None)
        return Estimate(mean, cov, used, z, time_s)
