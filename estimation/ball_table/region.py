"""Where the image stage does its pixel work: the region of interest around the table
and the window around the ball, in full-size pixels.

The coarse look (:func:`locate`) thresholds every COARSE_STEP_PX-th pixel of the raw RGB
frame: a box around the red top and the dark borders holding it, and a window around the
green ball. On a frame whose table region is tracked from the previous frame
(:class:`~observer_gym.estimation.ball_table.tracker.TableTracker`) the ball's coarse look
is confined to the region around the table (:func:`ball_window_near`), and
:func:`rect_inside` and :func:`trackable` are the tests the tracked region must pass.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import cv2
import numpy as np

from observer_gym.estimation.ball_table.ball_image import BALL_WINDOW_MARGIN_PX
from observer_gym.estimation.ball_table.features import BallTableFeatures
from observer_gym.estimation.ball_table.masks import (
    ROI_GREEN_HIGH,
    ROI_GREEN_LOW,
    ROI_RED_HIGH,
    ROI_RED_LOW,
    contour_holding,
    dark_mask,
    largest_contour,
)

COARSE_STEP_PX = 4  # the region-of-interest search looks at every 4th pixel
ROI_MARGIN_PX = 6  # a coarse pixel's reach (3) + the blur's (1) + 1 px outside + spare
# On a tracked frame, the ball's coarse look is confined to the table's region widened by
# this (the ball rests on the table; its top stands out over the far border by a few pixels).
BALL_NEAR_TABLE_PX = 16
# The coarse look's ball window: a coarse pixel's reach (3), a disc's curvature between
# sampled rows (< 1 px for rho >= 2), BALL_WINDOW_MARGIN_PX. A blob it cuts is looked for
# again (ball_image.ball_circle).
BALL_COARSE_MARGIN_PX = COARSE_STEP_PX + BALL_WINDOW_MARGIN_PX


class Located(NamedTuple):
    """What the coarse look (:func:`locate`) found, as boxes (x0, y0, x1, y1) of full-size
    pixels (end exclusive); None where nothing was seen."""

    table: tuple[int, int, int, int] | None  # the region of interest: red top + borders
    ball: tuple[int, int, int, int] | None  # a window around the ball's coarse pixels
    # Within ``table``, where the red top is (tracked from the previous frame only, see
    # TableTracker): the HLS conversion and the red mask are done there alone.
    red_top: tuple[int, int, int, int] | None = None


def coarse_image(rgb: np.ndarray) -> np.ndarray:
    """Every COARSE_STEP_PX-th pixel of the frame, for the coarse look (:func:`locate`)."""
    height, width = rgb.shape[:2]
    step = COARSE_STEP_PX
    return cv2.resize(rgb, (width // step, height // step), interpolation=cv2.INTER_NEAREST)


def _coarse_box(
    rect: Sequence[int], margin: int, image_size: tuple[int, int]
) -> tuple[int, int, int, int]:
    """The box (x0, y0, x1, y1) of full-size pixels around a rectangle (x, y, w, h) of
    coarse pixels, widened by ``margin``."""
    step = COARSE_STEP_PX
    x, y, w, h = rect
    return (
        max(x * step - margin, 0),
        max(y * step - margin, 0),
        min((x + w - 1) * step + 1 + margin, image_size[0]),
        min((y + h - 1) * step + 1 + margin, image_size[1]),
    )


def locate_ball(small: np.ndarray, image_size: tuple[int, int]) -> tuple[int, int, int, int] | None:
    """The coarse look's ball window: around every green pixel of the coarse image (the
    ball is the only green thing in view), widened by BALL_COARSE_MARGIN_PX."""
    green = cv2.boundingRect(cv2.inRange(small, ROI_GREEN_LOW, ROI_GREEN_HIGH))
    return _coarse_box(green, BALL_COARSE_MARGIN_PX, image_size) if green[2] else None


WHOLE_FRAME = "whole_frame"  # the ball's coarse look must cover the whole frame


def ball_window_near(
    rgb: np.ndarray, box: tuple[int, int, int, int]
) -> tuple[int, int, int, int] | str:
    """:func:`locate_ball`'s window from a coarse look confined to ``box`` (the tracked
    table's region) widened by BALL_NEAR_TABLE_PX: the same coarse pixels as the whole
    frame's (the part is aligned to their grid), and the ball rests on the table. WHOLE_FRAME
    when that look must cover the whole frame after all: no green there (the ball hidden,
    or elsewhere), green at the part's edge (the ball may reach beyond it), or a frame
    size the coarse grid does not divide."""
    step = COARSE_STEP_PX
    height, width = rgb.shape[:2]
    if width % step or height % step:
        return WHOLE_FRAME
    x0, y0, x1, y1 = box
    margin = BALL_NEAR_TABLE_PX
    x0, y0 = max(x0 - margin, 0) // step * step, max(y0 - margin, 0) // step * step
    x1, y1 = (
        min(-(-(x1 + margin) // step) * step, width),
        min(-(-(y1 + margin) // step) * step, height),
    )
    columns, rows = (x1 - x0) // step, (y1 - y0) // step
    small = cv2.resize(rgb[y0:y1, x0:x1], (columns, rows), interpolation=cv2.INTER_NEAREST)
    x, y, w, h = cv2.boundingRect(cv2.inRange(small, ROI_GREEN_LOW, ROI_GREEN_HIGH))
    if (
        w == 0
        or (x == 0 < x0)
        or (y == 0 < y0)
        or (x + w == columns and x1 < width)
        or (y + h == rows and y1 < height)
    ):
        return WHOLE_FRAME
    rect = (x + x0 // step, y + y0 // step, w, h)
    return _coarse_box(rect, BALL_COARSE_MARGIN_PX, (width, height))


def locate_table(
    small: np.ndarray, image_size: tuple[int, int]
) -> tuple[int, int, int, int] | None:
    """The coarse look's region of interest: a box around the red blob and the dark region
    that holds it (the borders; the largest dark thing in view can be the occluder),
    widened by ROI_MARGIN_PX."""
    red = cv2.inRange(small, ROI_RED_LOW, ROI_RED_HIGH)
    red_top = largest_contour(red, (0, 0))
    if red_top is None:
        return None
    table = contour_holding(cv2.bitwise_or(red, dark_mask(small)), (0, 0), red_top)
    return _coarse_box(cv2.boundingRect(table), ROI_MARGIN_PX, image_size)


def locate(rgb: np.ndarray) -> Located:
    """A look at every COARSE_STEP_PX-th pixel (:func:`coarse_image`): a box around the
    table (:func:`locate_table`) and a window around the ball (:func:`locate_ball`). A
    locator only, so it thresholds the RGB pixels directly (ROI_RED_*, ROI_GREEN_*), not in
    HLS."""
    height, width = rgb.shape[:2]
    small = coarse_image(rgb)
    return Located(locate_table(small, (width, height)), locate_ball(small, (width, height)))


def rect_inside(
    rect: tuple[int, int, int, int] | None, box: tuple[int, int, int, int], margin: int
) -> bool:
    """Whether a rectangle (x, y, w, h) lies ``margin`` or more inside a box (x0, y0, x1, y1)."""
    if rect is None:
        return False
    x, y, w, h = rect
    x0, y0, x1, y1 = box
    return x - x0 >= margin and y - y0 >= margin and x1 - x - w >= margin and y1 - y - h >= margin


def trackable(features: BallTableFeatures) -> bool:
    """Whether a frame's table can seed the next frame's region: its corners were found (a
    flagged frame cannot)."""
    return features.corners_px is not None
