"""The TargetFollower detector: the orange target's image state from a camera frame (OpenCV).

The target is the only saturated orange thing in the world
(envs/assets/target_follower_target.urdf).
Pixels whose HSV colour is orange are segmented, the largest connected blob is taken, and

- its centroid (image moments) gives (u, v), hence x_i = u - c_x, y_i = c_y - v;
- its area gives the width: a sphere of width W at depth z images as a disc of diameter
  f W / z (up to 1 % at the image's edge for the default camera), so
  d_x = s 2 sqrt(area / pi) sqrt(f_x / f_y). The renderer draws the sphere as a polygon
  mesh, whose area is about 3 % short of the disc's for targets of 15-60 px; the scale
  s = ``width_scale`` = 1.03 is that calibration (measured on rendered frames,
  tests/estimation/test_target_follower_observer.py).

A blob smaller than ``min_area_px`` (or none) is "no detection": the target is hidden,
outside the image, or too far. So is a blob that is not a whole disc, whose centroid and
area would be the visible part's, off by up to half the width, with no error model to
say so (:mod:`~observer_gym.estimation.target_follower.detector_error` measures whole
discs only):

- a blob touching the image's border (the target is cut by the image's edge);
- a blob whose bounding box is wider or taller than the disc of its area by more than
  ``max_extent_ratio`` (plus a pixel for the rim's rounding): a disc of area A has
  extent 2 sqrt(A / pi) in both directions (times sqrt(f_x / f_y) across), while a disc
  cut by a chord keeps its full extent along the chord and loses area (a half disc:
  1.41 times the diameter of its area); the target is partly hidden.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["TargetFollowerDetector"]


@dataclass(frozen=True)
class TargetFollowerDetector:
    """Orange-blob detector; thresholds in OpenCV's HSV (H in 0..179)."""

    hue_range: tuple[int, int] = (5, 25)
    min_saturation: int = 150
    min_value: int = 60
    min_area_px: int = 12
    width_scale: float = 1.03
    max_extent_ratio: float = 1.15

    def mask(self, image_rgb: np.ndarray) -> np.ndarray:
        """The binary mask of target-coloured pixels (uint8, 0 or 255)."""
        hsv = cv2.cvtColor(np.ascontiguousarray(image_rgb), cv2.COLOR_RGB2HSV)
        low = (self.hue_range[0], self.min_saturation, self.min_value)
        high = (self.hue_range[1], 255, 255)
        return cv2.inRange(hsv, low, high)

    def detect(self, image_rgb: np.ndarray, K: np.ndarray) -> np.ndarray | None:
        """(x_i, y_i, d_x) in pixels, or None when the target is not found."""
        mask = self.mask(image_rgb)
        count, _, stats, centroids = cv2.connectedComponentsWithStats(mask, connectivity=8)
        if count < 2:
            return None
        areas = stats[1:, cv2.CC_STAT_AREA]
        best = int(np.argmax(areas)) + 1
        area = float(stats[best, cv2.CC_STAT_AREA])
        if area < self.min_area_px:
            return None
        left, top, width_px, height_px = (int(v) for v in stats[best, :4])
        rows, cols = mask.shape
        if left == 0 or top == 0 or left + width_px == cols or top + height_px == rows:
            return None  # cut by the image's edge
        fx, fy = float(K[0, 0]), float(K[1, 1])
        # a whole disc of area A: extent 2 sqrt(A / pi) down, times sqrt(f_x / f_y) across
        diameter_px = 2.0 * math.sqrt(area / math.pi)
        extent = max(width_px * math.sqrt(fy / fx), height_px * math.sqrt(fx / fy))
        if extent > self.max_extent_ratio * diameter_px + 1.0:
            return None  # not a whole disc: partly hidden
        u, v = centroids[best]
        d_x = self.width_scale * diameter_px * math.sqrt(fx / fy)
        return np.array([u - K[0, 2], K[1, 2] - v, d_x])
