"""What a TargetFollower step delivers to an observer: the detection of its newest frame,
with the frame's capture time and the camera pose then.

The env's observation is the newest frame delivered so far (by capture time); a step may
deliver several frames (latency jitter) or none (a drop, or a frame still in flight), and
only the newest one's pixels (or perfect-detector report) reach the observer. So:

- :meth:`FrameReader.detect` turns one frame into (x_i, y_i, d_x) or None: the orange-blob
  detector (:class:`~observer_gym.estimation.target_follower.detector.TargetFollowerDetector`)
  on an rgb frame, the perfect detector's report in measurements mode; a non-finite entry
  (NaN, inf) is no detection;
- :meth:`FrameReader.newest` gives the step's new frame: the delivered frame with the
  latest capture time, if it is newer than every frame seen before (else the observation
  repeats an older frame and nothing new arrived), with its detection, capture time,
  nominal ``K`` and ``T_world_cam`` and the camera's tilt then
  (envs/target_follower/geometry.robot_pose_from_camera). Older frames delivered in the
  same step are lost to the observer (their content is not in the observation).

How far back a capture-time-fused observer keeps its past is the declared sensor's
``env.sensor_spec.history_s(step_s)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol, cast

import numpy as np
from gymnasium import spaces

from observer_gym.envs.target_follower import DETECTED, TARGET_PX, TargetFollowerEnv
from observer_gym.envs.target_follower.geometry import robot_pose_from_camera
from observer_gym.estimation.observer import checked_measurement, checked_rgb_frame
from observer_gym.estimation.target_follower.detector import TargetFollowerDetector

__all__ = ["FrameDetection", "FrameReader", "ImageDetector"]


class ImageDetector(Protocol):
    """What reads a frame: the blob detector, or the learned one (learned_detector.py)."""

    def detect(self, image: np.ndarray, K: np.ndarray) -> np.ndarray | None: ...


# Capture times closer than this are the same instant (tick multiples).
SAME_TIME_S = 1e-9


@dataclass(frozen=True)
class FrameDetection:
    """One delivered frame as an observer uses it."""

    z_px: np.ndarray | None  # (x_i, y_i, d_x) in pixels, None when not detected
    capture_time_s: float
    K: np.ndarray  # the nominal camera matrix
    T_world_cam: np.ndarray  # the nominal camera pose at capture
    tilt_rad: float  # the camera's tilt at capture


class FrameReader:
    """Detections of the frames a TargetFollower env delivers (see the module docstring).

    Args:
        env: the TargetFollower env (its obs_mode, image size, observation space and
            calibration are read).
        detector: the rgb detector (default: :class:`TargetFollowerDetector`; the learned
            observers pass the learned one).
        owner: the name in error messages.
    """

    def __init__(
        self,
        env: TargetFollowerEnv,
        detector: ImageDetector | None = None,
        owner: str = "TargetFollowerObserver",
    ) -> None:
        self.detector = detector or TargetFollowerDetector()
        self.from_pixels = env.config.obs_mode == "rgb"
        # measurements mode: its Dict (rgb mode: its Box, not read)
        self.measurement_space = cast(spaces.Dict, env.observation_space)
        self.image_size_px = (int(env.config.image_width_px), int(env.config.image_height_px))
        self.delta_y_m = env.calibration["delta_y_m"]
        self.owner = owner
        self.reset()

    def reset(self) -> None:
        self._newest_capture_s = -np.inf

    def detect(self, obs: Any, frame: dict) -> np.ndarray | None:
        """(x_i, y_i, d_x) of one frame, or None (also when an entry is NaN or inf)."""
        if self.from_pixels:
            image = checked_rgb_frame(
                obs, frame.get("image_size_px", self.image_size_px), self.owner
            )
            z = self.detector.detect(image, frame["K"])
        else:
            obs = checked_measurement(self.owner, obs, self.measurement_space)
            if not obs[DETECTED][0]:
                return None
            z = obs[TARGET_PX]
        if z is None:
            return None
        z = np.asarray(z, dtype=float)
        return z if bool(np.all(np.isfinite(z))) else None

    def newest(self, obs: Any, info: dict) -> FrameDetection | None:
        """The step's new frame (the observation's), detected; None when no frame newer
        than those seen before was delivered."""
        frames = info["frames"]
        if not frames:
            return None
        frame = max(frames, key=lambda f: f["capture_time_s"])
        capture_s = float(frame["capture_time_s"])
        if capture_s <= self._newest_capture_s + SAME_TIME_S:
            return None  # the observation repeats a frame seen before
        self._newest_capture_s = capture_s
        T_world_cam = np.asarray(frame["T_world_cam"], dtype=float)
        _, _, tilt = robot_pose_from_camera(T_world_cam, self.delta_y_m)
        return FrameDetection(
            self.detect(obs, frame),
            capture_s,
            np.asarray(frame["K"], dtype=float),
            T_world_cam,
            tilt,
        )
