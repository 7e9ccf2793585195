"""Table step 1 and step 2's findContours (docs/spec/table_ball.md, "Vision pipeline"):
the frame blurred and converted to HLS, the red top's and the dark borders' masks, and
the outlines found in them; also the colour thresholds on raw RGB that the coarse look
and the ball's window use.

Outlines keep every boundary pixel (CHAIN_APPROX_NONE rather than the spec's SIMPLE: the
corner refinement needs them all; the hull is the same).
"""

from __future__ import annotations

import cv2
import numpy as np

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


def largest_contour(mask: np.ndarray, offset: tuple[int, int]) -> np.ndarray | None:
    """Table step 2 / ball step 1: the largest external contour, every boundary pixel
    (CHAIN_APPROX_NONE rather than the spec's SIMPLE: the refinement needs them all; the
    hull is the same)."""
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE, offset=offset)
    if not contours:
        return None
    if len(contours) == 1:
        return contours[0]
    return max(contours, key=cv2.contourArea)


def contour_holding(mask: np.ndarray, offset: tuple[int, int], inner: np.ndarray) -> np.ndarray:
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


def touches_image_edge(rect: tuple[int, int, int, int], image_size: tuple[int, int]) -> bool:
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
    red_contour = largest_contour(red, red_offset)
    if red_contour is None:
        return None, None
    if red.shape == dark.shape:
        union = cv2.bitwise_or(red, dark)
    else:
        union = dark
        i, j = red_offset[1] - offset[1], red_offset[0] - offset[0]
        part = union[i : i + red.shape[0], j : j + red.shape[1]]
        cv2.bitwise_or(part, red, dst=part)
    return red_contour, contour_holding(union, offset, red_contour)
