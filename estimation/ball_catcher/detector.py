"""The BallCatcher detector: the green ball's image centre in a camera frame (OpenCV).

The rig's cameras see a white background, the grey box, the blue and orange arm and the
green ball, 3-12 px across at the default 320x240 and 75 deg. The image is first smoothed
by a 3x3 Gaussian (sigma 0.8 px, smaller than the smallest ball); the ball is then the
largest blob of strongly green pixels (HSV hue 40-85 of 180, saturation and value >= 80)
and its centre the blob's centroid (image moments). On the env's noiseless frames the
centroid is within 0.1 px RMS (0.095; 0.3 px at worst) of the projected centre (measured
in tests/estimation/test_ball_catcher_observer.py).

Why the smoothing: the colour test is per pixel, and under the env's image noise (up to
``image_noise_std`` = 64 per channel) many single pixels pass it by chance, most on the
grey box (202, 202, 191), where they join into blobs of 10-30 px: as large as the ball
at launch. Unsmoothed, over 10 throws at 64, 90 of 395 frames with the ball in view
reported such a blob; smoothed (the noise's std x 0.375), 11, and the ball's centroid
error fell from 0.28 / 0.32 to 0.16 / 0.19 px RMS (u / v). A 5x5 kernel leaves 4 false
of 395 but costs the noiseless frames 0.12 px RMS.

Blobs smaller than ``min_area_px`` pixels, and blobs touching the image's edge, are no
detection: their centroid is not the ball's centre (never silently wrong).
"""

from __future__ import annotations

import cv2
import numpy as np

GREEN_LOW_HSV = np.array([40, 80, 80], np.uint8)
GREEN_HIGH_HSV = np.array([85, 255, 255], np.uint8)
SMOOTHING_KERNEL_PX = (3, 3)  # the Gaussian's size; sigma from it (0.8 px), see above


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
        smoothed = cv2.GaussianBlur(image_rgb, SMOOTHING_KERNEL_PX, 0)
        hsv = cv2.cvtColor(smoothed, cv2.COLOR_RGB2HSV)
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
