"""The ball's pixel in one delivered BallCatcher frame, as every BallCatcher observer reads it.

``obs_mode="rgb"``: a detector (by default
:class:`~observer_gym.estimation.ball_catcher.detector.BallCatcherDetector`; the learned
observers' is :class:`~observer_gym.estimation.ball_catcher.learned_detector.LearnedBallDetector`)
on the frame's image (a uint8 H x W x 3 image of the frame's ``image_size_px``, else the
env config's size; others raise ``ValueError``). ``obs_mode="measurements"``: the env's
perfect-detector report ``uv_px`` ((2,) real numbers or None; others raise ``ValueError``).
Either way NaN, inf and pixels beyond ``MAX_PIXEL_PX`` are no detection.
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np

from observer_gym.estimation.ball_catcher.detector import BallCatcherDetector
from observer_gym.estimation.observer import (
    MAX_PIXEL_PX,
    checked_measurement_array,
    checked_rgb_frame,
)

__all__ = ["BallDetector", "FrameReader"]


class BallDetector(Protocol):
    """What reads the ball's pixel from an image (the blob detector, the learned one)."""

    def detect(self, image_rgb: np.ndarray) -> np.ndarray | None: ...


class FrameReader:
    """The ball's pixel (u, v) in a delivered frame (see the module docstring).

    Args:
        config: the env's config (its ``obs_mode`` and image size).
        detector: the rgb detector (default :class:`BallCatcherDetector`), any
            :class:`BallDetector`.
        owner: the observer's name, in error messages.
    """

    def __init__(
        self, config: Any, detector: BallDetector | None = None, owner: str = "observer"
    ) -> None:
        self.rgb = config.obs_mode == "rgb"
        self.image_size_px = (int(config.image_width_px), int(config.image_height_px))
        self.detector: BallDetector = detector if detector is not None else BallCatcherDetector()
        self.owner = owner

    def detect(self, frame: dict) -> np.ndarray | None:
        """The ball's pixel (u, v) in ``frame`` (an entry of ``info["frames"]``), or None
        (also for NaN, inf or beyond MAX_PIXEL_PX)."""
        if self.rgb:
            image = checked_rgb_frame(
                frame.get("image"),
                frame.get("image_size_px", self.image_size_px),
                f"{self.owner}: frame of camera {frame.get('camera_id')!r}",
            )
            uv = self.detector.detect(image)
        else:
            uv = frame.get("uv_px", "missing")  # None: no detection
            if uv is not None:
                uv = checked_measurement_array(self.owner, "uv_px", uv, (2,))
        if uv is None:
            return None
        uv = np.asarray(uv, dtype=float)
        # NaN, inf, or a pixel no camera reports (1e308 overflowed the filters' updates)
        return uv if bool(np.all(np.abs(uv) <= MAX_PIXEL_PX)) else None
