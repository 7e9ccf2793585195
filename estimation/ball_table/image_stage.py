"""The BallTable detector's image stage on one frame (pixels -> :class:`BallTableFeatures`):
the red top's four corners (table steps 1-4 and the ordering of step 5) and the ball's
image circle (ball step 1), docs/spec/table_ball.md, "Vision pipeline".

The outer outline of the red top plus the black borders (the borders' outer top edges) is
found too: it stands in when the red top gives no corners (the features say which model
the corners are), and beside the red top it sharpens the pose. :func:`extract_features`
finds the region of interest by the coarse look
(:func:`~observer_gym.estimation.ball_table.region.locate`); :func:`features_in_region`
works in a given one, which is how
:class:`~observer_gym.estimation.ball_table.tracker.TableTracker` reuses the previous
frame's. The steps themselves live in masks.py, ball_image.py and corners.py.

Frames smaller than the spec's 320x240 (a shorter focal length: the policy's 84 x 84 is
42 px) see the same scene smaller: the border probes' distance, a size in the scene,
shrinks with the focal length (scale.py); the pixel constants that stand for the pixel grid
itself (blur, clean-up, the refinement's margins) do not; approxPolyDP's tolerance has a
floor and the outline's corner offsets a slack of about a pixel (corners.py), and a square
too small to pin the tilt on its own gives no pose (geometry_stage.py).
"""

from __future__ import annotations

from typing import NamedTuple, overload

import numpy as np

from observer_gym.estimation.ball_table.ball_image import CUT, ball_circle
from observer_gym.estimation.ball_table.corners import (
    BORDER_PROBE_PX,
    bounding_rect,
    find_corners,
    image_axes,
    outline_beside_red_top,
)
from observer_gym.estimation.ball_table.features import BORDER_OUTLINE, RED_TOP, BallTableFeatures
from observer_gym.estimation.ball_table.masks import (
    blur,
    dark_mask,
    red_mask,
    table_outlines,
    to_hls,
)
from observer_gym.estimation.ball_table.region import Located, locate, rect_inside, trackable
from observer_gym.estimation.ball_table.scale import image_scale


def extract_features(rgb: np.ndarray, K: np.ndarray, T_world_cam: np.ndarray) -> BallTableFeatures:
    """The image stage on one RGB frame (uint8, HxWx3) with its calibration.

    ``T_world_cam`` only serves to name the corners (:func:`order_corners`). The pixel work
    is done on a region of interest around the table, found by a coarse look
    (:func:`locate`), which also finds the ball's window. For a sequence of frames,
    :class:`TableTracker` gives the same features, cheaper.
    """
    return features_in_region(rgb, K, T_world_cam, locate(rgb)).features


class RegionFeatures(NamedTuple):
    """:func:`features_in_region`'s result."""

    features: BallTableFeatures
    # (x, y, w, h) of the outline of red top + borders, full-size pixels; None if no red top
    outline_rect: tuple[int, int, int, int] | None
    red_rect: tuple[int, int, int, int] | None  # (x, y, w, h) of the red top's outline


@overload
def features_in_region(
    rgb: np.ndarray,
    K: np.ndarray,
    T_world_cam: np.ndarray,
    located: Located,
    inside_px: None = None,
) -> RegionFeatures: ...


@overload
def features_in_region(
    rgb: np.ndarray,
    K: np.ndarray,
    T_world_cam: np.ndarray,
    located: Located,
    inside_px: int,
) -> RegionFeatures | None: ...


def features_in_region(
    rgb: np.ndarray,
    K: np.ndarray,
    T_world_cam: np.ndarray,
    located: Located,
    inside_px: int | None = None,
) -> RegionFeatures | None:
    """The image stage in ``located``'s region of interest (the whole frame when it has
    none) and ball window; HLS and the red mask only in its ``red_top`` box, if given
    (else in the whole region; the ball's fallback converts the whole region when it needs
    it). The border probes read the raw frame, BORDER_PROBE_PX times the frame's
    :func:`~observer_gym.estimation.ball_table.scale.image_scale` from each side: half the
    borders' image width at every focal length up to the spec's camera's.

    With ``inside_px`` (regions tracked from the previous frame, :class:`TableTracker`):
    None, unless the outline of red top + borders and the red top's own outline each lie
    at least ``inside_px`` inside their region on every side, and the table's corners were
    found (a flagged frame is left to the full search). The regions then hold the table
    with at least the room around it that the coarse look's region leaves (ROI_MARGIN_PX
    less a coarse pixel's reach): the masks the outlines rest on are computed from true
    neighbours (3x3 blur; the open/close only ever meets non-red pixels there), and the
    features are the full search's (the border probes read the whole raw frame either
    way). ``inside_px`` needs ``located.table`` (ValueError without).
    """
    if inside_px is not None and located.table is None:
        raise ValueError("features_in_region: inside_px given without a table region to be inside")
    height, width = rgb.shape[:2]
    image_size = (width, height)
    x0, y0, x1, y1 = located.table or (0, 0, width, height)
    offset = (x0, y0)
    blurred = blur(rgb[y0:y1, x0:x1])  # table step 1
    if located.red_top is None:
        red_offset, red_hls = offset, to_hls(blurred)
        hls = red_hls  # the whole region's, for the ball's and the outline's fallbacks
    else:
        rx0, ry0, rx1, ry1 = located.red_top
        red_offset, hls = (rx0, ry0), None  # converted when a fallback needs it
        red_hls = to_hls(blurred[ry0 - y0 : ry1 - y0, rx0 - x0 : rx1 - x0])
    red_contour, outline_contour = table_outlines(  # table step 2
        red_mask(red_hls), dark_mask(blurred), offset, red_offset
    )
    outline_rect = None if outline_contour is None else bounding_rect(outline_contour)
    red_rect = None if red_contour is None else bounding_rect(red_contour)
    table = located.table
    if (
        inside_px is not None
        and table is not None  # checked above
        and not (
            rect_inside(outline_rect, table, inside_px)
            and rect_inside(red_rect, located.red_top or table, inside_px)
        )
    ):
        return None
    ball_px, ball_failure = ball_circle(rgb, located.ball, hls, offset)  # ball step 1
    if ball_failure is CUT:
        hls = to_hls(blurred)
        ball_px, ball_failure = ball_circle(rgb, None, hls, offset)
    axes = image_axes(K, T_world_cam)
    probe_px = BORDER_PROBE_PX * image_scale(K)
    red = find_corners(RED_TOP, red_contour, image_size, ball_px, rgb, axes, probe_px)
    if red[0] is not None:
        outline = outline_beside_red_top(outline_contour, red[0], image_size, ball_px)
    else:
        outline = find_corners(
            BORDER_OUTLINE, outline_contour, image_size, ball_px, rgb, axes, probe_px
        )
    features = assemble_features({RED_TOP: red, BORDER_OUTLINE: outline}, ball_px, ball_failure)
    if inside_px is not None and not trackable(features):
        return None
    return RegionFeatures(features, outline_rect, red_rect)


def assemble_features(
    found: dict[str, tuple[np.ndarray | None, str | None]],
    ball_px: np.ndarray | None,
    ball_failure: str | None,
) -> BallTableFeatures:
    """The features from each model's (corners, failure): the red top's corners when
    found, else the outline's."""
    red_corners, red_failure = found[RED_TOP]
    outline_corners, outline_failure = found[BORDER_OUTLINE]
    if red_corners is not None:
        return BallTableFeatures(red_corners, ball_px, RED_TOP, outline_corners, None, ball_failure)
    failure = f"{RED_TOP}: {red_failure}"
    if outline_corners is not None:
        return BallTableFeatures(
            outline_corners, ball_px, BORDER_OUTLINE, outline_corners, failure, ball_failure
        )
    failure += f"; {BORDER_OUTLINE}: {outline_failure}"
    return BallTableFeatures(None, ball_px, None, None, failure, ball_failure)
