"""The BallTable detector: docs/spec/table_ball.md's "Vision pipeline" in OpenCV, in two stages.

1. Image stage, :func:`extract_features` (pixels -> :class:`BallTableFeatures`): the red
   top's four corners (table steps 1-4 and the ordering of step 5) and the ball's image
   circle (ball step 1). The outer outline of the red top plus the black borders (the
   borders' outer top edges) is found too, as the report's future work suggests: it stands
   in when the red top gives no corners (the features say which model the corners are),
   and beside the red top it sharpens the pose.
2. Geometry stage, :class:`BallTableDetector` (features + calibration ->
   :class:`BallTableDetection`): PnP for the table's pose (table step 5), then the ball's
   position on the table (ball steps 2-4).

The measurements obs_mode already reports perfect features; :func:`features_from_measurement`
converts them, so the same geometry stage runs on both.

Beyond the spec, and why (numbers from tests/estimation/test_ball_table_detector.py on
155 rendered 320x240 frames, fixed camera and head motion, tilts within +-0.08 rad):

- Sub-pixel corners: each side's line is fitted to its outline pixels (cv2.fitLine) and
  moved out by the half-pixel bias of boundary pixel centres (:func:`refine_corners`).
  The renderer does not anti-alias, so a nearly horizontal side is only known to ~0.3 px
  whatever one does: corner RMSE 0.24 px, almost all of it in v.
- Those 0.24 px cost ~12 mrad of tilt RMSE when the red top's square is the only model:
  seen nearly head-on, a square's tilt is ill-conditioned. The borders' outer outline,
  3 cm higher, is found beside it in every clean frame, and the pose from all 8 corners
  (not coplanar; SQPNP) brings the tilt RMSE to 2.8 mrad and the ball's to 0.30 mm.
  Measured RMSE of tilt / ball position on the table:

  - default (red top + outline, 8 corners):       2.8 mrad / 0.30 mm
  - red top alone (``use_outline=False``), IPPE:  12.4 mrad / 0.99 mm
  - red top alone (``use_outline=False``), AP3P:  17.3 mrad / 1.14 mm
  - ``ball_radius="unknown"``: 0.31 mm, r within -0.39 ... +0.59 mm of 25 mm
  - perfect features (measurements obs_mode): worst frame < 0.001 mrad / 0.13 mm
  - outline alone (a red corner painted over): 8.1 mrad

  IPPE_SQUARE has the lower tilt error, so it is the default ``pnp_method``; with the
  outline both methods give the same pose (the square's PnP only runs when the joint
  pose fails, to tell why).
- Beside the red top, the outline's corners come from the red top's: its sides are cut
  where it reaches farthest toward each red corner, then refined like the red top's
  (:func:`outline_beside_red_top`); steps 2-5 run on the outline only when the red top
  gave no corners.
- The ball's centre is its blob's centroid, taken on the raw pixels of a window around
  the blob (0.05 px RMS against the exact ellipse; minEnclosingCircle's centre 0.13 px,
  and on the blurred mask the shading moved it 0.15 px): see :func:`ball_circle`.
- Bezier parameters are centred (see :func:`coarse_corners`); CHAIN_APPROX_NONE replaces
  SIMPLE (the refinement needs every boundary pixel; the hull is the same).
- Never silently wrong: an outline touching the image's edge, sides without a black
  border along them, corners that are no square or disagree with the outline, an
  implausible pose (tilt > 0.35 rad, yaw > 0.1 rad), a ball cut in parts, filling its
  circle badly, or whose image size does not fit its distance: each gives "not found" with
  a reason (``BallTableFeatures.table_failure``, ``BallTableDetection.failure``).

Cost (``python benchmarks/bench_detector.py``, one core): ~0.39 ms per frame, ~0.45 ms
with the observer's filters: 1.26-1.35x a bare OpenCV pass over the whole frame over nine
runs on a shared machine (medians of three 1.28-1.32; 1.5x before the tracked region).
Under heavier load on the same machine the same code measured 1.44-1.67x (0.66-0.74 ms
against 0.41-0.49 ms): the ~35 small calls per frame slow down more than the bare pass's
few whole-frame ones.
The pixel work is done on a region of interest around the table: on a sequence of frames
(:class:`TableTracker`, the observer's) the previous frame's, with HLS and the red mask in
the red top's part of it only; on the first frame, after a flagged one and when the table
left it, one found by a look at every 4th pixel
(:func:`locate`), which also finds the ball's window.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import NamedTuple

import cv2
import numpy as np

from observer_gym.envs.ball_table import geometry as geo
from observer_gym.envs.ball_table.layout import BALL_PX, CORNERS_PX, DETECTED

RED_TOP = "red_top"  # corners of the red top: (+-L/2, +-L/2, 0) in the table frame
BORDER_OUTLINE = "border_outline"  # outer top edges of the borders: (+-(L/2 + w), ., h)

# --- image stage parameters -------------------------------------------------------------
COARSE_STEP_PX = 4  # the region-of-interest search looks at every 4th pixel
ROI_MARGIN_PX = 6  # a coarse pixel's reach (3) + the blur's (1) + 1 px outside + spare
# A region tracked from the previous frame (TableTracker): its outline's box widened by
# TRACK_GROW_PX, kept when the new outline lies TRACK_INSIDE_PX inside it, the least room
# the coarse look's region leaves (ROI_MARGIN_PX less a coarse pixel's reach, 3).
TRACK_GROW_PX = 6
# ... and the coarse look for the ball there is confined to that region widened by this
# (the ball rests on the table; its top stands out over the far border by a few pixels).
BALL_NEAR_TABLE_PX = 16
TRACK_INSIDE_PX = ROI_MARGIN_PX - (COARSE_STEP_PX - 1)
ROI_RED_LOW, ROI_RED_HIGH = (107, 0, 0), (255, 60, 60)  # RGB; the red top is (203, 11, 11)
# RGB; the ball's lit to shaded green runs from (24, 202, 24) to (15, 122, 15)
ROI_GREEN_LOW, ROI_GREEN_HIGH = (0, 66, 0), (60, 255, 60)
BLUR_KSIZE = (3, 3)
# HLS thresholds (OpenCV units: H in [0, 180), L and S in [0, 255]) for the RGB frame
# converted as if it were BGR (see to_hls): red is at H = 120 there, green at H = 60.
# The rendered red top is (H, L, S) = (120, 107, 229), the black borders L ~ 10, the white
# background L = 255, the grey occluder L = 113 (top) and 82 (sides), S ~ 14.
RED_LOW, RED_HIGH = (110, 59, 120), (130, 180, 255)  # L 59: half-way red top / black
GREEN_LOW, GREEN_HIGH = (40, 25, 80), (88, 235, 255)  # H 88: about half-way green / red
# The borders in the outline mask: every channel of the blurred RGB <= 128, i.e. HSV value
# V <= 128, half-way between black (~10) and both the white background (255) and the
# arm's lit blue and orange (V ~ 240), which the arm below the table often touches. (The
# grey occluder, V ~ 127, joins in: no border, but it only ever breaks the outline, which
# the checks then reject.)
DARK_HIGH_RGB = (128, 128, 128)
BORDER_PROBE_MAX_L = 59  # a border pixel next to a side: darker than any red-top pixel
APPROX_EPSILON_FRACTION = 0.01  # approxPolyDP tolerance, of the image width (step 2)
BEZIER_PRODUCT_MAX = 1.5  # |t_a| |t_b| bound for a valid corner (step 4)
BALL_HULL_MARGIN_PX = 0.5  # hull points within rho + this of the ball are dropped (step 3)
BALL_EDGE_MARGIN_PX = 2.0  # the refinement ignores outline pixels within rho + this
SIDE_END_MARGIN_PX = 3  # the refinement leaves out this many pixels at each end of a side
MIN_SIDE_POINTS = 6
# Outline corner to red-top corner, of the red top's side: the borders' corner is 1.4 cm
# (w sqrt 2) out in the table plane plus their 3 cm height's parallax; measured 0.105-0.150
# on rendered frames (fixed camera, head motion up to 15 deg).
OUTLINE_CORNER_OFFSET_RANGE = (0.05, 0.3)
BORDER_PROBES = (0.2, 0.35, 0.5, 0.65, 0.8)  # where the border check looks along each side
BORDER_PROBE_PX = 2.0  # how far outside (red top) or inside (outline) a side it looks
BORDER_MIN_DARK_FRACTION = 0.75
BALL_WINDOW_MARGIN_PX = 3
# The coarse look's ball window: a coarse pixel's reach (3), a disc's curvature between
# sampled rows (< 1 px for rho >= 2), the margin above. A blob it cuts is looked for again.
BALL_COARSE_MARGIN_PX = COARSE_STEP_PX + BALL_WINDOW_MARGIN_PX
# minEnclosingCircle of the blob's boundary pixel centres is too small: they lie up to a
# pixel inside the outline (a half on average, less near the ends of the major axis, which
# set the circle). Measured on 492 rendered frames against the exact ellipse: 0.375 px
# short on average (std 0.09 px).
BALL_RADIUS_CORRECTION_PX = 0.4
MIN_BALL_RADIUS_PX = 2.0
# Blob pixels / enclosing circle's area: ~0.9 for the whole ball (its image is an ellipse,
# measured 0.81-0.95), ~0.5 for a half-hidden one, whose circle can be the whole one's.
MIN_BALL_FILL = 0.75

# --- geometry stage parameters ----------------------------------------------------------
PNP_METHODS = {"ippe_square": cv2.SOLVEPNP_IPPE_SQUARE, "ap3p": cv2.SOLVEPNP_AP3P}
# Corner reprojection bounds, measured on 492 clean rendered frames: RMS over the 4 corners
# of the PnP pose <= 0.75 px (IPPE_SQUARE) and <= 1.21 px (AP3P, which fits 3 corners
# exactly and leaves the 4th all the error); the largest of the 8 corners of the joint
# pose <= 0.63 px.
MAX_SQUARE_RMS_PX = 1.5
MAX_JOINT_REPROJECTION_PX = 1.0
MAX_PLAUSIBLE_TILT_RAD = 0.35  # the env allows at most 0.3 rad of commanded tilt
MAX_PLAUSIBLE_YAW_RAD = 0.1  # the arm keeps the table at its home yaw
BALL_DISTANCE_TOLERANCE = 0.2  # r known: |d / |p1 - t'| - 1| bound (a partly hidden ball)


class _ComparedByValue:
    """``==`` field by field, arrays by value (a dataclass's own ``==`` fails on arrays,
    and gymnasium's env checker compares the infos an observer puts these in)."""

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        return all(_same(getattr(self, f.name), getattr(other, f.name)) for f in fields(self))

    __hash__ = None  # mutable arrays inside


def _same(a, b) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return a is not None and b is not None and np.array_equal(a, b)
    return a == b


@dataclass(frozen=True, eq=False)
class BallTableFeatures(_ComparedByValue):
    """What the image stage found, in pixels (OpenCV convention).

    Attributes:
        corners_px: (4, 2) corners of ``corner_model`` in TABLE_CORNERS_TABLE order, or
            None when the table was not found.
        ball_px: (3,) centre u, v and semi-major radius of the ball's image, or None.
        corner_model: RED_TOP or BORDER_OUTLINE (which 3D corners ``corners_px`` are).
        outline_corners_px: (4, 2) corners of the borders' outer outline whenever they were
            found, also beside the red top's (the geometry stage then refines the pose on
            all 8 corners, which are not coplanar); None otherwise.
        table_failure: why the red top (and the outline) gave no corners, e.g.
            "red_top: clipped; border_outline: corners"; None when the red top worked.
        ball_failure: why no ball was reported; None when one was.
        source: "image" or "measurement".
    """

    corners_px: np.ndarray | None
    ball_px: np.ndarray | None
    corner_model: str | None = RED_TOP
    outline_corners_px: np.ndarray | None = None
    table_failure: str | None = None
    ball_failure: str | None = None
    source: str = "image"


@dataclass(frozen=True, eq=False)
class BallTableDetection(_ComparedByValue):
    """The geometry stage's result; every array is None when its part was not found.

    ``R_cam_table``, ``t_cam_table``: the table frame in the camera frame (PnP);
    ``T_world_table``: 4x4, through the frame's ``T_world_cam``; ``tilt_rad``: (tilt_x,
    tilt_y) of envs.ball_table.geometry; ``up_in_table``: Z_gnd,table = R_world_table^T e_z;
    ``ball_pos_table_m``: (x, y) of the ball's centre; ``ball_radius_m``: r (the estimate
    when the detector's ball radius is "unknown"); ``ball_distance_m``: d, camera to ball
    centre; ``corner_reprojection_px``: RMS reprojection error of the corners the pose
    rests on (4, or 8 after the joint refinement).
    """

    table_found: bool
    ball_found: bool
    corner_model: str | None = None
    R_cam_table: np.ndarray | None = None
    t_cam_table: np.ndarray | None = None
    T_world_table: np.ndarray | None = None
    tilt_rad: np.ndarray | None = None
    up_in_table: np.ndarray | None = None
    ball_pos_table_m: np.ndarray | None = None
    ball_radius_m: float | None = None
    ball_distance_m: float | None = None
    corner_reprojection_px: float | None = None
    failure: str | None = None


# === image stage =========================================================================
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
    rect: tuple[int, int, int, int], margin: int, image_size: tuple[int, int]
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
    red_top = _largest_contour(red, (0, 0))
    if red_top is None:
        return None
    table = _contour_holding(cv2.bitwise_or(red, dark_mask(small)), (0, 0), red_top)
    return _coarse_box(cv2.boundingRect(table), ROI_MARGIN_PX, image_size)


def locate(rgb: np.ndarray) -> Located:
    """A look at every COARSE_STEP_PX-th pixel (:func:`coarse_image`): a box around the
    table (:func:`locate_table`) and a window around the ball (:func:`locate_ball`). A
    locator only, so it thresholds the RGB pixels directly (ROI_RED_*, ROI_GREEN_*), not in
    HLS."""
    height, width = rgb.shape[:2]
    small = coarse_image(rgb)
    return Located(locate_table(small, (width, height)), locate_ball(small, (width, height)))


def blur(rgb: np.ndarray) -> np.ndarray:
    """Table step 1: Gaussian blur, 3x3. The renderer does not anti-alias, and a digital
    straight edge's mask is unchanged by this blur for any threshold between 37.5 % and
    62.5 % of the step (the [1 2 1] x [1 2 1] / 16 kernel), so every threshold below sits
    half-way between the two colours it separates."""
    return cv2.GaussianBlur(rgb, BLUR_KSIZE, 0)


def to_hls(rgb: np.ndarray) -> np.ndarray:
    """Table step 1: to HLS. The RGB frame is converted as if it were BGR, which swaps R and
    B: red moves to hue 120, so its range does not wrap around 0/180 (one inRange)."""
    return cv2.cvtColor(rgb, cv2.COLOR_BGR2HLS)


def red_mask(hls: np.ndarray) -> np.ndarray:
    """Table step 1: inRange on the red hue range, then the morphological clean-up."""
    return clean_mask(cv2.inRange(hls, RED_LOW, RED_HIGH))


def dark_mask(rgb: np.ndarray) -> np.ndarray:
    """The black borders (and other dark pixels) of the (blurred) RGB frame, for the
    outline."""
    return cv2.inRange(rgb, (0, 0, 0), DARK_HIGH_RGB)


_KERNEL = cv2.getStructuringElement(cv2.MORPH_RECT, (3, 3))
_KERNEL_5 = cv2.getStructuringElement(cv2.MORPH_RECT, (5, 5))


def clean_mask(mask: np.ndarray) -> np.ndarray:
    """Table step 1: morphological open (specks) then close (pinholes), 3x3. A digital
    straight edge survives both unchanged; corners are rounded by about a pixel.

    Written as erode 3x3, dilate 5x5, erode 3x3: the open's dilation and the close's
    are one 5x5 dilation (a 3x3 square plus a 3x3 square is a 5x5 one, also at the image's
    edge, which both ignore), so three passes instead of four; the masks are the same as
    morphologyEx's open then close (checked on every rendered frame of the benchmark and on
    random masks)."""
    return cv2.erode(cv2.dilate(cv2.erode(mask, _KERNEL), _KERNEL_5), _KERNEL)


def _largest_contour(mask: np.ndarray, offset: tuple[int, int]) -> np.ndarray | None:
    """Table step 2 / ball step 1: the largest external contour, every boundary pixel
    (CHAIN_APPROX_NONE rather than the spec's SIMPLE: the refinement needs them all; the
    hull is the same)."""
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE, offset=offset)
    if not contours:
        return None
    if len(contours) == 1:
        return contours[0]
    return max(contours, key=cv2.contourArea)


def _contour_holding(mask: np.ndarray, offset: tuple[int, int], inner: np.ndarray) -> np.ndarray:
    """The external contour of ``mask`` around the region ``inner`` (a contour of a part of
    ``mask``): the red top's own outline in the red + dark mask, not the largest dark
    thing in view (the grey occluder can be larger)."""
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE, offset=offset)
    if len(contours) == 1:
        return contours[0]
    seed = (float(inner[0, 0, 0]), float(inner[0, 0, 1]))
    for contour in contours:
        if cv2.pointPolygonTest(contour, seed, False) >= 0:
            return contour
    return max(contours, key=cv2.contourArea)  # not reached: mask holds inner


def _touches_image_edge(rect: tuple[int, int, int, int], image_size: tuple[int, int]) -> bool:
    """Whether a bounding rectangle (x, y, w, h) reaches the image's edge."""
    x, y, w, h = rect
    return x <= 0 or y <= 0 or x + w >= image_size[0] or y + h >= image_size[1]


def table_outlines(
    red: np.ndarray,
    dark: np.ndarray,
    offset: tuple[int, int],
    red_offset: tuple[int, int] | None = None,
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Table step 2's findContours: the red top's outline (the largest red blob) and the
    outer outline of red + dark around it (the borders' outer top edges). The union is not
    cleaned again: its parts are clean, and the blends between them that neither mask takes
    lie inside it. ``offset`` is the masks' top-left pixel in the frame; the red mask can
    cover a part of the dark one only, from ``red_offset``: then the union is made in
    ``dark`` itself (it is not needed after)."""
    red_offset = red_offset or offset
    red_contour = _largest_contour(red, red_offset)
    if red_contour is None:
        return None, None
    if red.shape == dark.shape:
        union = cv2.bitwise_or(red, dark)
    else:
        union = dark
        i, j = red_offset[1] - offset[1], red_offset[0] - offset[0]
        part = union[i : i + red.shape[0], j : j + red.shape[1]]
        cv2.bitwise_or(part, red, dst=part)
    return red_contour, _contour_holding(union, offset, red_contour)


_CUT = "cut"  # the ball's window cut its blob: look again in a wider one


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

    ``hls`` None (not converted yet): (None, _CUT) where it would be needed.
    """
    if window is not None:
        found = _ball_in_window(rgb, window, cut_is_final=False)
        if found[1] is not _CUT or hls is None:  # None: the caller converts, and asks again
            return found
    elif hls is None:
        return None, _CUT
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
    """:func:`ball_circle` in one window of the raw frame; (None, _CUT) when the blob
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
        return None, _CUT
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if len(contours) != 1:  # the ball cut in parts (by the occluder)
        return None, "partly_hidden"
    if _touches_image_edge((x0 + x, y0 + y, w, h), (width, height)):
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


class CoarseQuad(NamedTuple):
    """A quadrilateral found on an outline: its corners and, for each side, the range of
    the outline's pixels between the side's two hull vertices."""

    corners: list[tuple[float, float]]  # corner k ends side k (outline order)
    arcs: list[tuple[int, int]]  # side k: contour indices [start, end), cyclic


def coarse_corners(
    contour: np.ndarray | None, image_size: tuple[int, int], ball_px: np.ndarray | None
) -> tuple[CoarseQuad | None, str | None]:
    """Table steps 2-4 on an outline: convexHull, approxPolyDP (epsilon 1 % of the image
    width), hull points near the ball dropped, the 4 longest segments, their lines
    intersected. Returns the quadrilateral, or (None, reason): no outline, an outline
    touching the image's edge (clipped), or not exactly the 4 intersections of neighbouring
    segments valid corners.

    The Bezier parameters are measured from each segment's midpoint in half-lengths
    (t = 2 s - 1 for the Bezier parameter s in [0, 1]), so a segment's ends are |t| = 1 and
    two neighbouring sides extended to their common corner give |t_a| |t_b| ~ 1; a corner
    hidden over more than ~20 % of both its sides fails |t_a| |t_b| < 1.5. (Plain Python
    floats: a handful of 2D points, where NumPy's per-call cost would dominate.)
    """
    if contour is None:
        return None, "no_blob"
    hull_index = cv2.convexHull(contour, returnPoints=False).ravel()
    hull = contour[hull_index].reshape(-1, 2)
    if _touches_image_edge(cv2.boundingRect(hull), image_size):  # its extremes are the hull's
        return None, "clipped"
    poly = cv2.approxPolyDP(hull, APPROX_EPSILON_FRACTION * image_size[0], True)
    # Each vertex with its index in the contour, through its hull point.
    index_of = {(x, y): i for (x, y), i in zip(hull.tolist(), hull_index.tolist(), strict=True)}
    vertices = [(x, y, index_of[x, y]) for x, y in poly.reshape(-1, 2).tolist()]
    if ball_px is not None:  # step 3
        bu, bv, rho = ball_px.tolist()
        reach2 = (rho + BALL_HULL_MARGIN_PX) ** 2
        vertices = [p for p in vertices if (p[0] - bu) ** 2 + (p[1] - bv) ** 2 > reach2]
    n = len(vertices)
    if n < 4:
        return None, "corners"
    size = len(contour)
    # The hull runs along the contour one way or the other: one lap forward, or n - 1.
    forward = sum((vertices[i][2] - vertices[i - 1][2]) % size for i in range(n)) == size
    segments = []  # (squared length, x, y, dx, dy, arc), in outline order
    for i in range(n):
        (x, y, a), (x1, y1, b) = vertices[i], vertices[(i + 1) % n]
        dx, dy = x1 - x, y1 - y
        segments.append((dx * dx + dy * dy, x, y, dx, dy, (a, b) if forward else (b, a)))
    if n > 4:  # the 4 longest, still in outline order
        longest = sorted(sorted(range(n), key=lambda i: -segments[i][0])[:4])
        segments = [segments[i] for i in longest]
    corners = [(0.0, 0.0)] * 4
    for a in range(4):
        _, xa, ya, dxa, dya, _ = segments[a]
        for b in range(a + 1, 4):
            _, xb, yb, dxb, dyb, _ = segments[b]
            denominator = dxa * dyb - dya * dxb
            if abs(denominator) < 1e-9:
                if b - a != 2:
                    return None, "corners"  # neighbouring sides must meet
                continue
            gx, gy = xb - xa, yb - ya
            s_a = (gx * dyb - gy * dxb) / denominator
            s_b = (gx * dya - gy * dxa) / denominator
            valid = abs(2.0 * s_a - 1.0) * abs(2.0 * s_b - 1.0) < BEZIER_PRODUCT_MAX
            if b - a == 2:  # opposite sides
                if valid:
                    return None, "corners"
                continue
            if not valid:
                return None, "corners"
            corners[a if b == a + 1 else b] = (xa + s_a * dxa, ya + s_a * dya)
    return CoarseQuad(corners, [s[5] for s in segments]), None


def refine_corners(
    contour: np.ndarray, quad: CoarseQuad, ball_px: np.ndarray | None
) -> tuple[list[tuple[float, float]] | None, str | None]:
    """Sub-pixel corners, or (None, "refinement"): each side's line is fitted (cv2.fitLine)
    to the outline's pixels between its two hull vertices, less SIDE_END_MARGIN_PX at each
    end (rounded corners) and those near the ball; the lines are intersected.

    The outline's pixels are the region's boundary pixel centres, which lie inside the true
    edge: in each row (column) of a steep (flat) edge, between 0 and 1 pixel inside, on
    average 0.5 px, i.e. 0.5 max(|n_x|, |n_y|) along the edge's unit normal n. Moving the
    fitted line out by that much puts it on the midline between the last pixels inside and
    the first outside, which is unbiased.
    """
    size = len(contour)
    margin = SIDE_END_MARGIN_PX
    corners = quad.corners
    ball = None if ball_px is None else ball_px.tolist()
    lines = []
    for k, (start, end) in enumerate(quad.arcs):
        if (end - start) % size - 2 * margin < MIN_SIDE_POINTS:
            return None, "refinement"
        a, b = (start + margin) % size, (end - margin) % size
        points = contour[a:b] if a <= b else np.concatenate((contour[a:], contour[:b]))
        if ball is not None and _near_segment(
            *ball, corners[k - 1], corners[k], BALL_EDGE_MARGIN_PX
        ):
            offsets = points.reshape(-1, 2) - ball_px[:2]
            reach = ball[2] + BALL_EDGE_MARGIN_PX
            points = points[np.einsum("ij,ij->i", offsets, offsets) > reach * reach]
            if len(points) < MIN_SIDE_POINTS:
                return None, "refinement"
        lines.append(cv2.fitLine(points, cv2.DIST_L2, 0, 0.01, 0.01).ravel().tolist())
    return _intersect_sides(lines, corners)


def _near_segment(bu: float, bv: float, rho: float, start, end, margin: float) -> bool:
    """Whether the circle (bu, bv, rho) comes within ``margin`` (+ 1 px) of the segment
    start-end."""
    (x0, y0), (x1, y1) = start, end
    reach = rho + margin + 1.0
    dx, dy = x1 - x0, y1 - y0
    s = min(max(((bu - x0) * dx + (bv - y0) * dy) / (dx * dx + dy * dy), 0.0), 1.0)
    return (x0 + s * dx - bu) ** 2 + (y0 + s * dy - bv) ** 2 < reach * reach


def _intersect_sides(
    lines: list[list[float]], coarse: list[tuple[float, float]]
) -> tuple[list[tuple[float, float]] | None, str | None]:
    """Corner k where side k meets side k+1, after moving each fitted line (cv2.fitLine's
    vx, vy, x0, y0) out by the half-pixel bias (see :func:`refine_corners`)."""
    cx = 0.25 * (coarse[0][0] + coarse[1][0] + coarse[2][0] + coarse[3][0])
    cy = 0.25 * (coarse[0][1] + coarse[1][1] + coarse[2][1] + coarse[3][1])
    shifted = []
    for vx, vy, x0, y0 in lines:
        nx, ny = -vy, vx
        if (x0 - cx) * nx + (y0 - cy) * ny < 0.0:
            nx, ny = vy, -vx  # outward
        shift = 0.5 * max(abs(nx), abs(ny))
        shifted.append((x0 + shift * nx, y0 + shift * ny, vx, vy))
    corners = []
    for k in range(4):
        (px, py, ux, uy), (qx, qy, vx, vy) = shifted[k], shifted[k - 3]
        denominator = ux * vy - uy * vx
        if abs(denominator) < 1e-9:
            return None, "refinement"
        s = ((qx - px) * vy - (qy - py) * vx) / denominator
        corners.append((px + s * ux, py + s * uy))
    return corners, None


def image_axes(K: np.ndarray, T_world_cam: np.ndarray) -> list[list[float]]:
    """K d for d = R_world_cam^T e, e the world's +x and +y: how a point moving along them
    moves in the image (see :func:`order_corners`); once per frame, for both outlines."""
    return (K @ T_world_cam[:3, :2]).T.tolist()


def order_corners(
    corners: list[tuple[float, float]], axes: list[list[float]]
) -> list[tuple[float, float]] | None:
    """Table step 5's ordering, in TABLE_CORNERS_TABLE order: (+,+), (-,+), (-,-), (+,-).

    The table tilts by at most ~0.3 rad and keeps its home yaw, at which its x, y axes are
    the world's; so the signs of each corner's offset from the quadrilateral's centre along
    the images of world +x and +y (in that non-orthogonal image basis) name the corner.
    A point at pixel p moving along world direction e moves in the image along
    (K d)_uv - p (K d)_3 with d = R_world_cam^T e, whatever its depth (``axes``:
    :func:`image_axes`). None when the signs do not give one corner per quadrant.
    """
    cu = 0.25 * (corners[0][0] + corners[1][0] + corners[2][0] + corners[3][0])
    cv = 0.25 * (corners[0][1] + corners[1][1] + corners[2][1] + corners[3][1])
    kx, ky = axes
    ax, ay = kx[0] - cu * kx[2], kx[1] - cv * kx[2]
    bx, by = ky[0] - cu * ky[2], ky[1] - cv * ky[2]
    determinant = ax * by - ay * bx
    if abs(determinant) < 1e-12:
        return None
    ordered = [None] * 4
    for u, v in corners:
        du, dv = u - cu, v - cv
        along_x = (du * by - dv * bx) * determinant > 0.0
        along_y = (ax * dv - ay * du) * determinant > 0.0
        slot = _QUADRANT_SLOT[along_x, along_y]
        if ordered[slot] is not None:
            return None
        ordered[slot] = (u, v)
    return ordered


_QUADRANT_SLOT = {(True, True): 0, (False, True): 1, (False, False): 2, (True, False): 3}


def borders_confirmed(
    corners: list[tuple[float, float]],
    hls: np.ndarray,
    offset: tuple[int, int],
    ball_px: np.ndarray | None,
    outside: bool,
) -> bool:
    """Whether a black border runs along every side: just outside each side of the red top
    (``outside=True``) or just inside each side of the outer outline. A side made by
    something else (the occluder's edge, the image's edge, paint) fails. (Plain Python:
    a few dozen probes.)"""
    height, width = hls.shape[:2]
    pixel = hls.item  # (row, column, 1): the lightness, as a Python int
    ox, oy = offset
    cu = 0.25 * (corners[0][0] + corners[1][0] + corners[2][0] + corners[3][0])
    cv = 0.25 * (corners[0][1] + corners[1][1] + corners[2][1] + corners[3][1])
    shift = BORDER_PROBE_PX if outside else -BORDER_PROBE_PX
    bu, bv, reach2 = 0.0, 0.0, -1.0  # probes within reach of the ball's centre are skipped
    if ball_px is not None:
        bu, bv, rho = ball_px.tolist()
        reach2 = (rho + BORDER_PROBE_PX) ** 2
    for k in range(4):
        (x0, y0), (x1, y1) = corners[k], corners[k - 3]
        dx, dy = x1 - x0, y1 - y0
        length = math.hypot(dx, dy)
        nx, ny = -dy / length, dx / length
        if (x0 - cu) * nx + (y0 - cv) * ny < 0.0:
            nx, ny = -nx, -ny  # outward
        sx, sy = x0 + shift * nx, y0 + shift * ny
        used = dark = 0
        for f in BORDER_PROBES:
            x, y = sx + f * dx, sy + f * dy
            if (x - bu) ** 2 + (y - bv) ** 2 <= reach2:
                continue
            i, j = round(x) - ox, round(y) - oy
            if 0 <= i < width and 0 <= j < height:
                used += 1
                if pixel(j, i, 1) < BORDER_PROBE_MAX_L:
                    dark += 1
        if used < 3 or dark < BORDER_MIN_DARK_FRACTION * used:
            return False
    return True


def check_corners(
    corners: list[tuple[float, float]],
    hls: np.ndarray,
    offset: tuple[int, int],
    ball_px: np.ndarray | None,
    axes: list[list[float]],
    model: str,
) -> tuple[np.ndarray | None, str | None]:
    """Refined corners of ``model`` named (table step 5's ordering) and their borders
    confirmed, as a (4, 2) array, or (None, reason)."""
    ordered = order_corners(corners, axes)
    if ordered is None:
        return None, "ordering"
    if not borders_confirmed(ordered, hls, offset, ball_px, outside=model == RED_TOP):
        return None, "borders"
    return np.array(ordered), None


def find_corners(
    model: str,
    contour: np.ndarray | None,
    image_size: tuple[int, int],
    ball_px: np.ndarray | None,
    hls: np.ndarray,
    offset: tuple[int, int],
    axes: list[list[float]],
) -> tuple[np.ndarray | None, str | None]:
    """Table steps 2-5 (up to PnP) on one outline: its named corners, or (None, reason)."""
    quad, failure = coarse_corners(contour, image_size, ball_px)
    if quad is None:
        return None, failure
    corners, failure = refine_corners(contour, quad, ball_px)
    if corners is None:
        return None, failure
    return check_corners(corners, hls, offset, ball_px, axes, model)


def outline_beside_red_top(
    contour: np.ndarray | None,
    red_corners: np.ndarray,
    image_size: tuple[int, int],
    ball_px: np.ndarray | None,
) -> tuple[np.ndarray | None, str | None]:
    """The borders' outline's named corners once the red top's are known, or (None,
    reason): the cheap path beside the red top, in place of steps 2-5 on the outline.

    Outline corner k is the outline's farthest pixel from the red top's centre in the
    direction of red corner k (the borders run parallel to the red top's sides, a few
    pixels out), which names it; it must lie OUTLINE_CORNER_OFFSET_RANGE of the red top's
    side from red corner k. Those 4 pixels cut the outline into its sides, which are
    refined like the red top's (:func:`refine_corners`). No border probes here: the joint
    pose checks all 8 corners against each other (``BallTableDetector.table_pose``), and a
    side made by anything but the borders puts its two corners off by more than that
    allows; on the occluder and head-motion frames of the tests the same frames are found
    with or without them.
    """
    if contour is None:
        return None, "no_blob"
    if _touches_image_edge(cv2.boundingRect(contour), image_size):
        return None, "clipped"
    red = red_corners.tolist()
    cu = 0.25 * (red[0][0] + red[1][0] + red[2][0] + red[3][0])
    cv = 0.25 * (red[0][1] + red[1][1] + red[2][1] + red[3][1])
    directions = np.array([[x - cu for x, _ in red], [y - cv for _, y in red]])
    points = contour.reshape(-1, 2)
    index = (points @ directions).argmax(axis=0).tolist()
    coarse = points[index].tolist()
    dist = math.dist
    r0, r1, r2, r3 = red
    side = 0.25 * (dist(r3, r0) + dist(r0, r1) + dist(r1, r2) + dist(r2, r3))
    low, high = OUTLINE_CORNER_OFFSET_RANGE[0] * side, OUTLINE_CORNER_OFFSET_RANGE[1] * side
    c0, c1, c2, c3 = coarse
    if not (
        low <= dist(r0, c0) <= high
        and low <= dist(r1, c1) <= high
        and low <= dist(r2, c2) <= high
        and low <= dist(r3, c3) <= high
    ):
        return None, "corners"
    size = len(points)
    i0, i1, i2, i3 = index
    forward = (i0 - i3) % size + (i1 - i0) % size + (i2 - i1) % size + (i3 - i2) % size == size
    if not forward:
        if (i3 - i0) % size + (i0 - i1) % size + (i1 - i2) % size + (i2 - i3) % size != size:
            return None, "corners"
        arcs = [(i0, i3), (i1, i0), (i2, i1), (i3, i2)]
    else:
        arcs = [(i3, i0), (i0, i1), (i1, i2), (i2, i3)]
    corners, failure = refine_corners(contour, CoarseQuad(coarse, arcs), ball_px)
    if corners is None:
        return None, failure
    return np.array(corners), None


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


def features_in_region(
    rgb: np.ndarray,
    K: np.ndarray,
    T_world_cam: np.ndarray,
    located: Located,
    inside_px: int | None = None,
) -> RegionFeatures | None:
    """The image stage in ``located``'s region of interest (the whole frame when it has
    none) and ball window; HLS and the red mask only in its ``red_top`` box, if given
    (else in the whole region; the ball's and the outline's fallbacks convert the whole
    region when they need it).

    With ``inside_px`` (regions tracked from the previous frame, :class:`TableTracker`):
    None, unless the outline of red top + borders and the red top's own outline each lie
    at least ``inside_px`` inside their region on every side, and the table's corners were
    found (a flagged frame is left to the full search). The regions then hold the table
    with at least the room around it that the coarse look's region leaves (ROI_MARGIN_PX
    less a coarse pixel's reach): the masks the outlines rest on are computed from true
    neighbours (3x3 blur; the open/close only ever meets non-red pixels there), the border
    probes (BORDER_PROBE_PX outside the red top) fall inside the red top's box, and the
    features are the full search's.
    """
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
    outline_rect = None if outline_contour is None else cv2.boundingRect(outline_contour)
    red_rect = None if red_contour is None else cv2.boundingRect(red_contour)
    if inside_px is not None and not (
        rect_inside(outline_rect, located.table, inside_px)
        and rect_inside(red_rect, located.red_top or located.table, inside_px)
    ):
        return None
    ball_px, ball_failure = ball_circle(rgb, located.ball, hls, offset)  # ball step 1
    if ball_failure is _CUT:
        hls = to_hls(blurred)
        ball_px, ball_failure = ball_circle(rgb, None, hls, offset)
    axes = image_axes(K, T_world_cam)
    red = find_corners(RED_TOP, red_contour, image_size, ball_px, red_hls, red_offset, axes)
    if red[0] is not None:
        outline = outline_beside_red_top(outline_contour, red[0], image_size, ball_px)
    else:
        hls = to_hls(blurred) if hls is None else hls
        outline = find_corners(
            BORDER_OUTLINE, outline_contour, image_size, ball_px, hls, offset, axes
        )
    features = assemble_features({RED_TOP: red, BORDER_OUTLINE: outline}, ball_px, ball_failure)
    if inside_px is not None and not trackable(features):
        return None
    return RegionFeatures(features, outline_rect, red_rect)


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


class TableTracker:
    """:func:`extract_features` on the frames of one camera in order, with the table's region
    of interest tracked from frame to frame instead of searched for.

    The table moves little between frames (at most 2 px of its outline's box per 20 ms
    frame on the benchmark's episodes, fixed camera and head motion), so the region of a
    frame is the previous frame's outline box widened by TRACK_GROW_PX, HLS and the red
    mask are done in the previous red top's box widened as much only, and
    :func:`features_in_region` accepts them when both outlines lie TRACK_INSIDE_PX inside
    their boxes and the table's corners are found (i.e. the table moved by at most
    TRACK_GROW_PX - TRACK_INSIDE_PX). Else, and on the first frame and after a frame whose
    table was flagged, the whole frame is searched (:func:`locate`): a flagged frame always
    comes from the full search, and a tracked one gives the full search's features
    (tests/estimation/test_ball_table_detector.py). The ball's window comes from the coarse
    look, as in the full search, confined to the region around the table when the ball is
    seen well inside it (:func:`ball_window_near`).

    ``tracked_frames`` and ``searched_frames`` count the frames of each path since the
    tracker was made (a frame whose tracked region failed counts as searched).
    """

    def __init__(self) -> None:
        # (region of interest, red top's box), as (x0, y0, x1, y1), or None: search
        self.boxes: tuple[tuple[int, int, int, int], tuple[int, int, int, int]] | None = None
        self.tracked_frames = 0
        self.searched_frames = 0

    def reset(self) -> None:
        """Forget the table (a new episode): the next frame is searched."""
        self.boxes = None

    def extract_features(
        self, rgb: np.ndarray, K: np.ndarray, T_world_cam: np.ndarray
    ) -> BallTableFeatures:
        height, width = rgb.shape[:2]
        image_size = (width, height)
        small = ball_window = None
        if self.boxes is not None:
            ball_window = ball_window_near(rgb, self.boxes[0])
            if ball_window is WHOLE_FRAME:
                small = coarse_image(rgb)
                ball_window = locate_ball(small, image_size)
            located = Located(self.boxes[0], ball_window, self.boxes[1])
            found = features_in_region(rgb, K, T_world_cam, located, TRACK_INSIDE_PX)
            if found is not None:
                self.tracked_frames += 1
                self.boxes = tracked_boxes(found, image_size)
                return found.features
        self.searched_frames += 1
        if small is None:
            small = coarse_image(rgb)
            ball_window = locate_ball(small, image_size)
        located = Located(locate_table(small, image_size), ball_window)
        found = features_in_region(rgb, K, T_world_cam, located)
        self.boxes = tracked_boxes(found, image_size) if trackable(found.features) else None
        return found.features


def tracked_boxes(
    found: RegionFeatures, image_size: tuple[int, int]
) -> tuple[tuple[int, int, int, int], tuple[int, int, int, int]]:
    """The next frame's region of interest and red top's box: the outline's and the red
    top's boxes widened by TRACK_GROW_PX (the red top's within the region)."""
    table = _grown(found.outline_rect, TRACK_GROW_PX, (0, 0, *image_size))
    return table, _grown(found.red_rect, TRACK_GROW_PX, table)


def _grown(
    rect: tuple[int, int, int, int], grow: int, bounds: tuple[int, int, int, int]
) -> tuple[int, int, int, int]:
    """The box (x0, y0, x1, y1) of a rectangle (x, y, w, h) widened by ``grow``, within
    ``bounds`` (x0, y0, x1, y1)."""
    x, y, w, h = rect
    return (
        max(x - grow, bounds[0]),
        max(y - grow, bounds[1]),
        min(x + w + grow, bounds[2]),
        min(y + h + grow, bounds[3]),
    )


def features_from_measurement(obs: dict) -> BallTableFeatures:
    """Features from a measurements-mode observation (perfect red-top corners and ball
    circle), respecting its ``detected`` flags."""
    table_seen, ball_seen = (bool(flag) for flag in obs[DETECTED])
    corners = np.asarray(obs[CORNERS_PX], dtype=np.float64).reshape(4, 2) if table_seen else None
    ball = np.asarray(obs[BALL_PX], dtype=np.float64) if ball_seen else None
    return BallTableFeatures(
        corners,
        ball,
        RED_TOP if table_seen else None,
        None,
        None if table_seen else "not_detected",
        None if ball_seen else "not_detected",
        source="measurement",
    )


# === geometry stage ======================================================================
def _model_square(model: str) -> tuple[float, float]:
    """(side, height above the top) of the square whose corners ``model`` names."""
    if model == BORDER_OUTLINE:
        return geo.TABLE_SIDE_M + 2.0 * geo.BORDER_WIDTH_M, geo.BORDER_HEIGHT_M
    return geo.TABLE_SIDE_M, 0.0


_CORNER_SIGNS = np.sign(geo.TABLE_CORNERS_TABLE[:, :2])
# IPPE_SQUARE's object points are (-s/2, s/2), (s/2, s/2), (s/2, -s/2), (-s/2, -s/2): in
# TABLE_CORNERS_TABLE order ((+,+), (-,+), (-,-), (+,-)) those are corners 1, 0, 3, 2.
_IPPE_ORDER = [1, 0, 3, 2]


def model_corners_table(model: str) -> np.ndarray:
    """(4, 3) corners of ``model`` in the table frame, in TABLE_CORNERS_TABLE order."""
    side, height = _model_square(model)
    return np.column_stack([0.5 * side * _CORNER_SIGNS, np.full(4, height)])


# The joint pose's 8 corners: red top, then outline. They are not coplanar, so the joint
# pose is solved by SQPNP (global; on 492 rendered frames it matched cv2.solvePnPRefineLM
# from the square's pose to 0.1 mrad of tilt RMSE, at a third of its cost).
_JOINT_CORNERS_TABLE = np.vstack(
    [model_corners_table(RED_TOP), model_corners_table(BORDER_OUTLINE)]
)
_CORNERS_TABLE = {
    RED_TOP: model_corners_table(RED_TOP).tolist(),
    BORDER_OUTLINE: model_corners_table(BORDER_OUTLINE).tolist(),
    "joint": _JOINT_CORNERS_TABLE.tolist(),
}


def _pnp_square(model: str, flag: int) -> tuple[np.ndarray, list[int] | None]:
    """The model's square at z = 0 (its own frame) and the image-point order for ``flag``."""
    square = np.column_stack([0.5 * _model_square(model)[0] * _CORNER_SIGNS, np.zeros(4)])
    if flag == cv2.SOLVEPNP_IPPE_SQUARE:
        return square[_IPPE_ORDER], _IPPE_ORDER
    return square, None


_PNP_SQUARES = {
    (model, flag): _pnp_square(model, flag)
    for model in (RED_TOP, BORDER_OUTLINE)
    for flag in PNP_METHODS.values()
}


def _reprojection_px(points_table: list, corners_px: np.ndarray, K, R_cam_table, t_cam_table):
    """Each corner's reprojection error, px (inf if a corner is behind the camera). Plain
    Python floats: a few points, where NumPy's per-call cost would dominate."""
    (r0, r1, r2), (tx, ty, tz) = R_cam_table.tolist(), t_cam_table.tolist()
    (fx, _, cx), (_, fy, cy), _ = K.tolist()
    errors = []
    for (x, y, z), (u, v) in zip(points_table, corners_px.tolist(), strict=True):
        depth = r2[0] * x + r2[1] * y + r2[2] * z + tz
        if depth <= 0.0:
            return [math.inf]
        u_hat = fx * (r0[0] * x + r0[1] * y + r0[2] * z + tx) / depth + cx
        v_hat = fy * (r1[0] * x + r1[1] * y + r1[2] * z + ty) / depth + cy
        errors.append(math.hypot(u_hat - u, v_hat - v))
    return errors


def _rms(values: list[float]) -> float:
    return math.sqrt(sum(value * value for value in values) / len(values))


class BallTableDetector:
    """The geometry stage: table pose by PnP, ball position on the table.

    Args:
        pnp_method: "ippe_square" (default: IPPE for a planar square; the lower tilt error
            on rendered frames, see the module docstring) or "ap3p" (the report's).
        ball_radius: "known" (r = BALL_RADIUS_M: the ball's centre is where its viewing ray
            meets the plane z_table = r) or "unknown" (r and d both from p1_z = r and
            d = r / sin(alpha), the report's choice).
        use_outline: when the features hold the borders' outline beside the red top,
            solve the pose again on all 8 corners (SQPNP), once the square's PnP has
            vouched for the red top. The outline lies 3 cm above the top, and these
            non-coplanar points pin the tilt far better than one square seen nearly
            head-on (see the module docstring).
    """

    def __init__(
        self, pnp_method: str = "ippe_square", ball_radius: str = "known", use_outline: bool = True
    ) -> None:
        if pnp_method not in PNP_METHODS:
            raise ValueError(f"pnp_method must be one of {sorted(PNP_METHODS)}, got {pnp_method!r}")
        if ball_radius not in ("known", "unknown"):
            raise ValueError(f"ball_radius must be 'known' or 'unknown', got {ball_radius!r}")
        self.pnp_method = pnp_method
        self.ball_radius = ball_radius
        self.use_outline = use_outline
        self._flag = PNP_METHODS[pnp_method]

    def detect(
        self, features: BallTableFeatures, K: np.ndarray, T_world_cam: np.ndarray
    ) -> BallTableDetection:
        """Table pose and ball position from the image stage's features."""
        if features.corners_px is None:
            return BallTableDetection(False, False, failure=f"table: {features.table_failure}")
        pose = self.table_pose(features, K)
        if isinstance(pose, str):
            return BallTableDetection(False, False, features.corner_model, failure=pose)
        R_cam_table, t_cam_table, reprojection_px = pose
        T_cam_table = np.eye(4)
        T_cam_table[:3, :3], T_cam_table[:3, 3] = R_cam_table, t_cam_table
        T_world_table = T_world_cam @ T_cam_table
        R_world_table = T_world_table[:3, :3]
        tilt_x, tilt_y = geo.tilt_angles(R_world_table)  # TRF is parallel to the world at home
        yaw_rad = math.atan2(R_world_table[1, 0], R_world_table[0, 0])
        if (
            max(abs(tilt_x), abs(tilt_y)) > MAX_PLAUSIBLE_TILT_RAD
            or abs(yaw_rad) > MAX_PLAUSIBLE_YAW_RAD
        ):
            return BallTableDetection(
                False, False, features.corner_model, failure="table: implausible pose"
            )
        table = {
            "corner_model": features.corner_model,
            "R_cam_table": R_cam_table,
            "t_cam_table": t_cam_table,
            "T_world_table": T_world_table,
            "tilt_rad": np.array([tilt_x, tilt_y]),
            "up_in_table": R_world_table[2].copy(),  # Z_gnd,table = R_world_table^T e_z
            "corner_reprojection_px": reprojection_px,
        }
        if features.ball_px is None:
            return BallTableDetection(
                True, False, **table, failure=f"ball: {features.ball_failure}"
            )
        ball = self.ball_position(features.ball_px, K, R_cam_table, t_cam_table)
        if isinstance(ball, str):
            return BallTableDetection(True, False, **table, failure=ball)
        position, radius, distance = ball
        return BallTableDetection(
            True,
            True,
            **table,
            ball_pos_table_m=position,
            ball_radius_m=radius,
            ball_distance_m=distance,
        )

    def table_pose(self, features: BallTableFeatures, K: np.ndarray):
        """Table step 5: PnP -> (R_cam_table, t_cam_table, RMS corner reprojection px), or
        the reason the pose was rejected.

        With the outline beside the red top, the joint 8-corner pose comes first: when it
        fits every corner within MAX_JOINT_REPROJECTION_PX it also vouches for the red top
        (the square's own PnP could only fit its 4 corners better, well within
        MAX_SQUARE_RMS_PX), so the square's PnP only runs when the joint pose fails, to
        tell why: the red top is no square, or it and the outline disagree.
        """
        corners_px, model = features.corners_px, features.corner_model
        outline = features.outline_corners_px
        if self.use_outline and model == RED_TOP and outline is not None:
            joint = self._joint_pose(np.concatenate((corners_px, outline)), K)
            if not isinstance(joint, str):
                return joint
            square = self._square_pose(corners_px, model, K)
            return square if isinstance(square, str) else joint
        return self._square_pose(corners_px, model, K)

    def _square_pose(self, corners_px: np.ndarray, model: str, K: np.ndarray):
        """The pose from one model's 4 corners (``pnp_method``), or why it was rejected."""
        square_points, image_order = _PNP_SQUARES[(model, self._flag)]
        image_points = corners_px[image_order] if image_order is not None else corners_px
        ok, rvec, tvec = cv2.solvePnP(square_points, image_points, K, None, flags=self._flag)
        if not ok:
            return "table: PnP failed"
        R_cam_table, _ = cv2.Rodrigues(rvec)
        height = _model_square(model)[1]
        t_cam_table = tvec.reshape(3) - height * R_cam_table[:, 2]  # square at z = height
        errors_px = _reprojection_px(_CORNERS_TABLE[model], corners_px, K, R_cam_table, t_cam_table)
        if not _rms(errors_px) <= MAX_SQUARE_RMS_PX:
            return "table: corners are no square"
        return R_cam_table, t_cam_table, _rms(errors_px)

    @staticmethod
    def _joint_pose(points_px: np.ndarray, K: np.ndarray):
        """The pose from the red top's and the outline's 8 corners (SQPNP), or why it was
        rejected."""
        ok, rvec, tvec = cv2.solvePnP(
            _JOINT_CORNERS_TABLE, points_px, K, None, flags=cv2.SOLVEPNP_SQPNP
        )
        if not ok:
            return "table: joint PnP failed"
        R_cam_table, _ = cv2.Rodrigues(rvec)
        t_cam_table = tvec.reshape(3)
        errors_px = _reprojection_px(
            _CORNERS_TABLE["joint"], points_px, K, R_cam_table, t_cam_table
        )
        if not max(errors_px) <= MAX_JOINT_REPROJECTION_PX:
            return "table: red top and border outline disagree"
        return R_cam_table, t_cam_table, _rms(errors_px)

    def ball_position(self, ball_px, K, R_cam_table, t_cam_table):
        """Ball steps 2-4 -> (ball_pos_table_m (2,), r, d), or the reason it was rejected.

        The same geometry as camera_geometry.pixel_ray and ray_plane_intersection through
        the camera's pose in the table frame (tests/estimation check they agree), written
        with plain floats for speed: ~10x cheaper than NumPy on 3-vectors.
        """
        u, v, rho = (float(x) for x in ball_px[:3])
        (fx, _, cx), (_, fy, cy), _ = K.tolist()
        # Step 2: the major axis's vertices c +- rho e, e the unit vector from the principal
        # point toward c (any direction when c is at the principal point).
        norm = math.hypot(u - cx, v - cy)
        ex, ey = ((u - cx) / norm, (v - cy) / norm) if norm > 1e-9 else (1.0, 0.0)
        R, t = R_cam_table.tolist(), t_cam_table.tolist()
        # Step 4's t' = -R^T t: the camera's centre in the table frame.
        eye = [-(R[0][i] * t[0] + R[1][i] * t[1] + R[2][i] * t[2]) for i in range(3)]

        def ray(pu: float, pv: float) -> list[float]:
            """Unit ray R^T K^-1 (pu, pv, 1) in the table frame (step 3; v1 = R^T v0)."""
            x, y = (pu - cx) / fx, (pv - cy) / fy
            d = [R[0][i] * x + R[1][i] * y + R[2][i] for i in range(3)]
            n = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
            return [d[0] / n, d[1] / n, d[2] / n]

        v_a, v_b = ray(u + rho * ex, v + rho * ey), ray(u - rho * ex, v - rho * ey)
        cos_2alpha = v_a[0] * v_b[0] + v_a[1] * v_b[1] + v_a[2] * v_b[2]
        sin_alpha = math.sin(0.5 * math.acos(min(max(cos_2alpha, -1.0), 1.0)))  # step 3
        v1 = [v_a[i] + v_b[i] for i in range(3)]  # the centre's ray: along v_a + v_b
        n = math.sqrt(v1[0] * v1[0] + v1[1] * v1[1] + v1[2] * v1[2])
        v1 = [v1[0] / n, v1[1] / n, v1[2] / n]
        if sin_alpha <= 0.0:
            return "ball: no size"
        if self.ball_radius == "known":
            # p1 = t' + s v1 on the plane z_table = r (ray-plane intersection).
            radius = geo.BALL_RADIUS_M
            if v1[2] >= 0.0 or eye[2] <= radius:
                return "ball: its ray misses the table"
            distance = (radius - eye[2]) / v1[2]
            if abs(radius / sin_alpha / distance - 1.0) > BALL_DISTANCE_TOLERANCE:
                return "ball: its image size does not fit its distance (partly hidden?)"
        else:
            # p1_z = t'_z + d v1_z = r with d = r / sin(alpha): r (1 - v1_z / sin a) = t'_z.
            radius = eye[2] / (1.0 - v1[2] / sin_alpha)
            if not 0.0 < radius < 0.5 * geo.TABLE_SIDE_M:
                return "ball: implausible radius"
            distance = radius / sin_alpha  # step 3's d = r / sin(alpha)
        position = np.array([eye[0] + distance * v1[0], eye[1] + distance * v1[1]])
        return position, radius, distance
