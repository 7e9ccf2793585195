"""Ball step 1 (docs/spec/table_ball.md, "Vision pipeline"): the ball's image circle,
centre (u, v) and radius rho in pixels, from the raw frame.

The centre is the centroid of the ball's blob, taken on the raw pixels of a window around
it: 0.05 px RMS against the exact ellipse, where minEnclosingCircle's centre gave 0.13 px
and the blurred mask's shading moved it 0.15 px (see :func:`ball_circle`). A ball cut in
parts, filling its circle badly, too small or touching the image's edge is not reported;
the reason is.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from observer_gym.estimation.ball_table.masks import (
    GREEN_HIGH,
    GREEN_LOW,
    ROI_GREEN_HIGH,
    ROI_GREEN_LOW,
    touches_image_edge,
)

BALL_WINDOW_MARGIN_PX = 3  # the ball's window reaches this far past its blob's box
# minEnclosingCircle of the blob's boundary pixel centres is too small: they lie up to a
# pixel inside the outline (a half on average, less near the ends of the major axis, which
# set the circle). Measured on 492 rendered frames against the exact ellipse: 0.375 px
# short on average (std 0.09 px).
BALL_RADIUS_CORRECTION_PX = 0.4
MIN_BALL_RADIUS_PX = 2.0
# Blob pixels / enclosing circle's area: ~0.9 for the whole ball (its image is an ellipse,
# measured 0.81-0.95), ~0.5 for a half-hidden one, whose circle can be the whole one's.
MIN_BALL_FILL = 0.75


CUT = "cut"  # the ball's window cut its blob: look again in a wider one


def ball_circle(
    rgb: np.ndarray,
    window: tuple[int, int, int, int] | None,
    hls: np.ndarray | None,
    offset: tuple[int, int],
) -> tuple[np.ndarray | None, str | None]:
    """Ball step 1 -> ((u, v, rho), None) or (None, reason).

    inRange on green gives the ball's blob (the only green thing in view), in a window of
    the raw frame: the coarse look's (:func:`locate`) or, when that saw no green or its
    window cuts the blob, the one around every green pixel of the blurred region of
    interest (``hls``, at ``offset``). Raw pixels, because the blur blends the ball's
    shaded green with the red top, and where a blend crosses a fixed hue threshold depends
    on the shade (more of the dark side's edge is lost): on rendered frames that moved the
    centre 0.15 px toward the light; the renderer draws flat colours, so the raw mask is
    exact. Its centroid is the centre c (the centroid of a filled ellipse is its centre:
    0.05 px RMS against the exact ellipse, where minEnclosingCircle's centre, set by two
    or three extreme pixels, gave 0.13 px); minEnclosingCircle gives rho, plus
    BALL_RADIUS_CORRECTION_PX (the boundary pixel centres lie inside the outline).

    ``hls`` None (not converted yet): (None, CUT) where it would be needed.
    """
    if window is not None:
        found = _ball_in_window(rgb, window, cut_is_final=False)
        if found[1] is not CUT or hls is None:  # None: the caller converts, and asks again
            return found
    elif hls is None:
        return None, CUT
    x, y, w, h = cv2.boundingRect(cv2.inRange(hls, GREEN_LOW, GREEN_HIGH))
    if w == 0:
        return None, "no_blob"
    height, width = rgb.shape[:2]
    x, y = x + offset[0], y + offset[1]
    margin = BALL_WINDOW_MARGIN_PX
    window = (
        max(x - margin, 0),
        max(y - margin, 0),
        min(x + w + margin, width),
        min(y + h + margin, height),
    )
    return _ball_in_window(rgb, window, cut_is_final=True)


def _ball_in_window(
    rgb: np.ndarray, window: tuple[int, int, int, int], cut_is_final: bool
) -> tuple[np.ndarray | None, str | None]:
    """:func:`ball_circle` in one window of the raw frame; (None, CUT) when the blob
    reaches a side of the window that is not the image's edge (unless ``cut_is_final``).
    The raw pixels are flat colours, so green is thresholded in RGB (ROI_GREEN_*): the
    same mask as GREEN_* in HLS on every rendered frame checked (402, with the occluder
    and head motion), without converting the window."""
    x0, y0, x1, y1 = window
    height, width = rgb.shape[:2]
    mask = cv2.inRange(rgb[y0:y1, x0:x1], ROI_GREEN_LOW, ROI_GREEN_HIGH)
    x, y, w, h = cv2.boundingRect(mask)
    if w == 0:
        return None, "no_blob"
    if not cut_is_final and (
        (x == 0 < x0) or (y == 0 < y0) or (x0 + x + w == x1 < width) or (y0 + y + h == y1 < height)
    ):
        return None, CUT
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if len(contours) != 1:  # the ball cut in parts (by the occluder)
        return None, "partly_hidden"
    if touches_image_edge((x0 + x, y0 + y, w, h), (width, height)):
        return None, "clipped"
    _, rho = cv2.minEnclosingCircle(contours[0])
    rho += BALL_RADIUS_CORRECTION_PX
    if rho < MIN_BALL_RADIUS_PX:
        return None, "too_small"
    moments = cv2.moments(mask, binaryImage=True)
    if moments["m00"] < MIN_BALL_FILL * math.pi * rho * rho:  # a partly hidden ball
        return None, "partly_hidden"
    u = x0 + moments["m10"] / moments["m00"]
    v = y0 + moments["m01"] / moments["m00"]
    return np.array([u, v, rho]), None
