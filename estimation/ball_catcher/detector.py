"""The BallCatcher detector: the green ball's image centre in a camera frame (OpenCV).

The rig's cameras see a white background, the grey box, the blue and orange arm and the
green ball, 3-12 px across at the default 320x240 and 75 deg. The ball is the largest
blob of strongly green pixels (HSV hue 40-85 of 180, saturation and value >= 80); its
centre is the blob's centroid (image moments), which for these small, unblurred blobs
is within 0.1 px RMS (0.3 px at worst) of the projected centre (measured in
tests/estimation/test_ball_catcher_observer.py). Blobs smaller than ``min_area_px``
pixels, and blobs touching the image's edge, are no detection: their centroid is not the
ball's centre (never silently wrong).
"""

from __future__ import annotations

import cv2
import numpy as np

GREEN_LOW_HSV = np.array([40, 80, 80], np.uint8)
GREEN_HIGH_HSV = np.array([85, 255, 255], np.uint8)


class BallCatcherDetector:
    """Finds the ball in RGB frames.

    Args:
        min_area_px: smallest blob (pixels) taken as the ball.
    """

    def __init__(self, min_area_px: int = 3) -> None:
        if int(min_area_px) != min_area_px or min_area_px < 1:
            raise ValueError(f"BallCatcherDetector: min_area_px = {min_area_px!r}, must be >= 1")
        self.min_area_px = int(min_area_px)

    def detect(self, image_rgb: np.ndarray) -> np.ndarray | None:
        """The ball's centre (u, v) in pixels, or None when it is not in the frame."""
        hsv = cv2.cvtColor(image_rgb, cv2.COLOR_RGB2HSV)
        mask = cv2.inRange(hsv, GREEN_LOW_HSV, GREEN_HIGH_HSV)
        count, _, stats, centroids = cv2.connectedComponentsWithStats(mask, connectivity=8)
        if count < 2:  # label 0 is the background
            return None
        best = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
        x, y, w, h, area = stats[best]
        if area < self.min_area_px:
            return None
        height, width = mask.shape
        if x == 0 or y == 0 or x + w == width or y + h == height:
            return None  # cut by the image's edge: its centroid is not the ball's centre
        return np.asarray(centroids[best], dtype=float)
