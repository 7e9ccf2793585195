"""What every BallTable observer does first with a step: find the step's new frame and read
its features (and, for the observers that work on the table's pose, the detection).

A step's observation is the newest frame delivered so far (envs/core.py); ``info["frames"]``
lists the frames delivered this step, in capture order. So the observation is a new frame
exactly when the newest of those was captured after every frame seen before: with latency
jitter a step can deliver only a frame older than one already delivered, and the
observation is then the old frame again, which must not be fused twice.

Frames (``obs_mode="rgb"``) must be uint8 images of the env's size (``image_size_px`` of the
frame, else the env config's), H x W x 3; measurements must have the keys and shapes of the
env's measurement space. Anything else raises ``ValueError`` before any state changes.
"""

from __future__ import annotations

from typing import Any, cast

import numpy as np
from gymnasium import spaces

from observer_gym.envs.ball_table import BallTableEnv
from observer_gym.estimation.ball_table.features import (
    BallTableDetection,
    BallTableFeatures,
    features_from_measurement,
)
from observer_gym.estimation.ball_table.geometry_stage import BallTableDetector
from observer_gym.estimation.ball_table.tracker import TableTracker
from observer_gym.estimation.observer import (
    MAX_PIXEL_PX,
    checked_measurement,
    checked_rgb_frame,
)

__all__ = ["FrameReader", "detected_parts", "finite_or_none"]


class FrameReader:
    """The new frame of each step, its features (image stage, or the measurement's perfect
    features) and its detection (geometry stage: PnP and the ball on the table).

    Args:
        env: the (unwrapped) BallTable env the frames come from.
        detector: the geometry stage (default :class:`BallTableDetector`).
        owner: the observer's name, for error messages.
    """

    def __init__(
        self, env: BallTableEnv, detector: BallTableDetector | None = None, owner: str = ""
    ) -> None:
        cfg = env.config
        self.owner = owner or type(self).__name__
        self.detector = detector or BallTableDetector()
        self.from_pixels = cfg.obs_mode == "rgb"
        # measurements mode: its Dict (rgb mode: its Box, not read)
        self.measurement_space = cast(spaces.Dict, env.observation_space)
        self.image_size_px = (int(cfg.image_width_px), int(cfg.image_height_px))
        # The image stage, with the table's region of interest tracked between frames.
        self.table_tracker = TableTracker()
        self.reset()

    def reset(self) -> None:
        self.table_tracker.reset()
        self._newest_capture_s = -np.inf

    def new_frame(self, obs: Any, info: dict) -> tuple[dict | None, Any]:
        """(the info of the frame the step's observation holds, the observation checked) if
        that frame is new, else (None, None): no frame this step, or only frames older than
        one seen before. The observation is checked whenever frames arrived (ValueError)."""
        frames = info["frames"]
        if not frames:
            return None, None
        frame = frames[-1]
        if self.from_pixels:
            size_px = frame.get("image_size_px", self.image_size_px)
            obs = checked_rgb_frame(obs, size_px, self.owner)
        else:
            obs = checked_measurement(self.owner, obs, self.measurement_space)
        if not frame["capture_time_s"] > self._newest_capture_s:
            return None, None
        return frame, obs

    def features(self, obs: Any, frame: dict) -> BallTableFeatures:
        """The image stage's features of the new ``frame`` whose picture or measurement is
        ``obs`` (both from :meth:`new_frame`); the frame counts as seen from now on."""
        if self.from_pixels:
            features = self.table_tracker.extract_features(obs, frame["K"], frame["T_world_cam"])
        else:
            # A pixel no camera reports (1e308: its rays cancel, ZeroDivisionError in the
            # geometry stage) is a non-finite one: no detection of that part.
            obs = {k: np.where(np.abs(v) <= MAX_PIXEL_PX, v, np.nan) for k, v in obs.items()}
            features = features_from_measurement(obs)
        self._newest_capture_s = float(frame["capture_time_s"])
        return features

    def mark_seen(self, frame: dict) -> None:
        """The new ``frame`` counts as seen, its picture read by another image stage (the
        learned detector's)."""
        self._newest_capture_s = float(frame["capture_time_s"])

    def detect(self, obs: Any, frame: dict) -> BallTableDetection:
        """The detection of the new ``frame`` (its :meth:`features` through the geometry
        stage)."""
        features = self.features(obs, frame)
        return self.detector.detect(features, frame["K"], frame["T_world_cam"])


def finite_or_none(value: np.ndarray | None) -> np.ndarray | None:
    """``value`` as a float array if all of it is finite, else None (no detection)."""
    if value is None:
        return None
    value = np.asarray(value, dtype=float)
    return value if bool(np.all(np.isfinite(value))) else None


def detected_parts(
    detection: BallTableDetection | None,
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(tilt, ball position on the table) of a detection, each None when not found or not
    finite (NaN, inf: e.g. from NaN pixels in a measurement)."""
    if detection is None:
        return None, None
    tilt = detection.tilt_rad if detection.table_found else None
    ball = detection.ball_pos_table_m if detection.ball_found else None
    return finite_or_none(tilt), finite_or_none(ball)
