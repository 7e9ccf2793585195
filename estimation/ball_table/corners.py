"""Table steps 2-5 up to PnP (docs/spec/table_ball.md, "Vision pipeline") on one
outline: its four corners, sub-pixel, named in TABLE_CORNERS_TABLE order and checked.

:func:`find_corners` runs them in turn: hull, approxPolyDP, the hull points near the ball
dropped, the 4 longest segments intersected (:func:`coarse_corners`; Bezier parameters
measured from each segment's midpoint); each side's line fitted to its outline pixels and
moved out by the half-pixel bias of boundary pixel centres (:func:`refine_corners`); the
corners named (:func:`order_corners`) and a black border confirmed along every side
(:func:`borders_confirmed`, on the raw frame). The renderer does not anti-alias, so a
nearly horizontal side is only known to ~0.3 px whatever one does: corner RMSE 0.24 px,
almost all of it in v (tests/estimation/test_ball_table_detector.py, 155 rendered 320x240
frames; at 84 x 84, 0.12 px in u and 0.35 px in v:
tests/estimation/test_ball_table_small_frames.py).

Beside the red top's corners, the borders' outline takes a cheaper path
(:func:`outline_beside_red_top`): its sides are cut where it reaches farthest toward each
red corner, then refined like the red top's.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import cv2
import numpy as np

from observer_gym.estimation.ball_table.features import RED_TOP
from observer_gym.estimation.ball_table.masks import touches_image_edge

# A border pixel next to a side: its lightness (max + min) / 2 on the raw frame below this,
# darker than any red-top pixel (black ~10, red top 107, grey occluder 82 and 113).
BORDER_PROBE_MAX_L = 59
APPROX_EPSILON_FRACTION = 0.01  # approxPolyDP tolerance, of the image width (step 2)
# ... but at least this: a digital straight side's hull strays up to 1 px from the side's
# line, and the mask's clean-up rounds the corners by about a pixel more. Below 200 px of
# width, 1 % is less (0.84 px at 84 px), and a side came out as two segments.
APPROX_EPSILON_MIN_PX = 2.0
BEZIER_PRODUCT_MAX = 1.5  # |t_a| |t_b| bound for a valid corner (step 4)
BALL_HULL_MARGIN_PX = 0.5  # hull points within rho + this of the ball are dropped (step 3)
BALL_EDGE_MARGIN_PX = 2.0  # the refinement ignores outline pixels within rho + this
SIDE_END_MARGIN_PX = 3  # the refinement leaves out this many pixels at each end of a side
MIN_SIDE_POINTS = 6
# Outline corner to red-top corner, of the red top's side: the borders' corner is 1.4 cm
# (w sqrt 2) out in the table plane plus their 3 cm height's parallax; measured 0.105-0.150
# on rendered frames (fixed camera, head motion up to 15 deg). The outline's corner is one
# of its pixels, and the red top's corner is known to a fraction of one: the range is
# widened by OUTLINE_CORNER_SLACK_PX at either end, which matters when the side is short
# (at 84 x 84 px, a 30 px side: offsets measured 1.34-3.57 px, 0.044-0.117 of the side).
OUTLINE_CORNER_OFFSET_RANGE = (0.05, 0.3)
OUTLINE_CORNER_SLACK_PX = 1.0
BORDER_PROBES = (0.2, 0.35, 0.5, 0.65, 0.8)  # where the border check looks along each side
# How far outside (red top) or inside (outline) a side it looks, at the spec's 320x240
# (focal length 160 px): half the borders' image width there (~4 px); the image stage
# scales it with the focal length (scale.image_scale: 0.525 px at 84 x 84).
BORDER_PROBE_PX = 2.0
BORDER_MIN_DARK_FRACTION = 0.75


def bounding_rect(points: np.ndarray) -> tuple[int, int, int, int]:
    """cv2.boundingRect of ``points`` (a contour, a mask) as the (x, y, w, h) it is."""
    x, y, w, h = cv2.boundingRect(points)
    return x, y, w, h


class CoarseQuad(NamedTuple):
    """A quadrilateral found on an outline: its corners and, for each side, the range of
    the outline's pixels between the side's two hull vertices."""

    corners: list[tuple[float, float]]  # corner k ends side k (outline order)
    arcs: list[tuple[int, int]]  # side k: contour indices [start, end), cyclic


def coarse_corners(
    contour: np.ndarray | None, image_size: tuple[int, int], ball_px: np.ndarray | None
) -> tuple[CoarseQuad | None, str | None]:
    """Table steps 2-4 on an outline: convexHull, approxPolyDP (epsilon 1 % of the image
    width, at least APPROX_EPSILON_MIN_PX), hull points near the ball dropped, the 4
    longest segments, their lines intersected. Returns the quadrilateral, or (None,
    reason): no outline, an outline touching the image's edge (clipped), or not exactly the
    4 intersections of neighbouring segments valid corners.

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
    if touches_image_edge(bounding_rect(hull), image_size):  # its extremes are the hull's
        return None, "clipped"
    epsilon = max(APPROX_EPSILON_FRACTION * image_size[0], APPROX_EPSILON_MIN_PX)
    poly = cv2.approxPolyDP(hull, epsilon, True)
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
    ball: tuple[float, float, float] | None = None  # (u, v, rho)
    if ball_px is not None:
        bu, bv, rho = ball_px.tolist()
        ball = (bu, bv, rho)
    lines = []
    for k, (start, end) in enumerate(quad.arcs):
        if (end - start) % size - 2 * margin < MIN_SIDE_POINTS:
            return None, "refinement"
        a, b = (start + margin) % size, (end - margin) % size
        points = contour[a:b] if a <= b else np.concatenate((contour[a:], contour[:b]))
        if ball is not None and _near_segment(
            ball, corners[k - 1], corners[k], BALL_EDGE_MARGIN_PX
        ):
            offsets = points.reshape(-1, 2) - ball[:2]
            reach = ball[2] + BALL_EDGE_MARGIN_PX
            points = points[np.einsum("ij,ij->i", offsets, offsets) > reach * reach]
            if len(points) < MIN_SIDE_POINTS:
                return None, "refinement"
        lines.append(cv2.fitLine(points, cv2.DIST_L2, 0, 0.01, 0.01).ravel().tolist())
    return _intersect_sides(lines, corners)


def _near_segment(
    ball: tuple[float, float, float],
    start: tuple[float, float],
    end: tuple[float, float],
    margin: float,
) -> bool:
    """Whether the circle ``ball`` (u, v, rho) comes within ``margin`` (+ 1 px) of the
    segment start-end."""
    bu, bv, rho = ball
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
    ordered: list[tuple[float, float] | None] = [None] * 4
    for u, v in corners:
        du, dv = u - cu, v - cv
        along_x = (du * by - dv * bx) * determinant > 0.0
        along_y = (ax * dv - ay * du) * determinant > 0.0
        slot = _QUADRANT_SLOT[along_x, along_y]
        if ordered[slot] is not None:
            return None
        ordered[slot] = (u, v)
    # the four corners took the four slots, one each: none is left None
    return [corner for corner in ordered if corner is not None]


_QUADRANT_SLOT = {(True, True): 0, (False, True): 1, (False, False): 2, (True, False): 3}


def borders_confirmed(
    corners: list[tuple[float, float]],
    rgb: np.ndarray,
    ball_px: np.ndarray | None,
    outside: bool,
    probe_px: float = BORDER_PROBE_PX,
) -> bool:
    """Whether a black border runs along every side: ``probe_px`` just outside each side
    of the red top (``outside=True``) or just inside each side of the outer outline. A side
    made by something else (the occluder's edge, the image's edge, paint) fails. The probes
    read the raw frame ``rgb`` (full size), whose pixels are the renderer's flat colours:
    a border one pixel wide (84 x 84 frames) is black there, where the blur has mixed it
    with its neighbours. (Plain Python: a few dozen probes.)"""
    height, width = rgb.shape[:2]
    pixel = rgb.item  # (row, column, channel), as a Python int
    cu = 0.25 * (corners[0][0] + corners[1][0] + corners[2][0] + corners[3][0])
    cv = 0.25 * (corners[0][1] + corners[1][1] + corners[2][1] + corners[3][1])
    shift = probe_px if outside else -probe_px
    bu, bv, reach2 = 0.0, 0.0, -1.0  # probes within reach of the ball's centre are skipped
    if ball_px is not None:
        bu, bv, rho = ball_px.tolist()
        reach2 = (rho + probe_px) ** 2
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
            i, j = round(x), round(y)
            if 0 <= i < width and 0 <= j < height:
                used += 1
                r, g, b = pixel(j, i, 0), pixel(j, i, 1), pixel(j, i, 2)
                if max(r, g, b) + min(r, g, b) < 2 * BORDER_PROBE_MAX_L:  # HLS lightness
                    dark += 1
        if used < 3 or dark < BORDER_MIN_DARK_FRACTION * used:
            return False
    return True


def check_corners(
    corners: list[tuple[float, float]],
    rgb: np.ndarray,
    ball_px: np.ndarray | None,
    axes: list[list[float]],
    model: str,
    probe_px: float = BORDER_PROBE_PX,
) -> tuple[np.ndarray | None, str | None]:
    """Refined corners of ``model`` named (table step 5's ordering) and their borders
    confirmed (:func:`borders_confirmed` on the raw frame ``rgb``, ``probe_px`` from each
    side), as a (4, 2) array, or (None, reason)."""
    ordered = order_corners(corners, axes)
    if ordered is None:
        return None, "ordering"
    if not borders_confirmed(ordered, rgb, ball_px, model == RED_TOP, probe_px):
        return None, "borders"
    return np.array(ordered), None


def find_corners(
    model: str,
    contour: np.ndarray | None,
    image_size: tuple[int, int],
    ball_px: np.ndarray | None,
    rgb: np.ndarray,
    axes: list[list[float]],
    probe_px: float = BORDER_PROBE_PX,
) -> tuple[np.ndarray | None, str | None]:
    """Table steps 2-5 (up to PnP) on one outline: its named corners, or (None, reason)."""
    if contour is None:
        return None, "no_blob"
    quad, failure = coarse_corners(contour, image_size, ball_px)
    if quad is None:
        return None, failure
    corners, failure = refine_corners(contour, quad, ball_px)
    if corners is None:
        return None, failure
    return check_corners(corners, rgb, ball_px, axes, model, probe_px)


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
    side (+- OUTLINE_CORNER_SLACK_PX) from red corner k. Those 4 pixels cut the outline
    into its sides, which are refined like the red top's (:func:`refine_corners`). No
    border probes here: the joint pose checks all 8 corners against each other
    (``BallTableDetector.table_pose``), and a side made by anything but the borders puts
    its two corners off by more than that allows; on the occluder and head-motion frames of
    the tests the same frames are found with or without them.
    """
    if contour is None:
        return None, "no_blob"
    if touches_image_edge(bounding_rect(contour), image_size):
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
    slack = OUTLINE_CORNER_SLACK_PX
    low = OUTLINE_CORNER_OFFSET_RANGE[0] * side - slack
    high = OUTLINE_CORNER_OFFSET_RANGE[1] * side + slack
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
