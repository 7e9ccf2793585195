"""The image stage on the frames of one camera in order (:class:`TableTracker`, the
observer's), with the table's region of interest tracked from frame to frame instead of
searched for, and the same features as the full search.
"""

from __future__ import annotations

import numpy as np

from observer_gym.estimation.ball_table.features import BallTableFeatures
from observer_gym.estimation.ball_table.image_stage import RegionFeatures, features_in_region
from observer_gym.estimation.ball_table.region import (
    COARSE_STEP_PX,
    ROI_MARGIN_PX,
    Located,
    ball_window_near,
    coarse_image,
    locate_ball,
    locate_table,
    trackable,
)

# A region tracked from the previous frame (TableTracker): its outline's box widened by
# TRACK_GROW_PX, kept when the new outline lies TRACK_INSIDE_PX inside it, the least room
# the coarse look's region leaves (ROI_MARGIN_PX less a coarse pixel's reach, 3).
TRACK_GROW_PX = 6
TRACK_INSIDE_PX = ROI_MARGIN_PX - (COARSE_STEP_PX - 1)


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
        small: np.ndarray | None = None
        ball_window: tuple[int, int, int, int] | None = None
        if self.boxes is not None:
            near = ball_window_near(rgb, self.boxes[0])
            if isinstance(near, str):  # WHOLE_FRAME, its only other value
                small = coarse_image(rgb)
                ball_window = locate_ball(small, image_size)
            else:
                ball_window = near
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
        searched = features_in_region(rgb, K, T_world_cam, located)
        self.boxes = tracked_boxes(searched, image_size) if trackable(searched.features) else None
        return searched.features


def tracked_boxes(
    found: RegionFeatures, image_size: tuple[int, int]
) -> tuple[tuple[int, int, int, int], tuple[int, int, int, int]]:
    """The next frame's region of interest and red top's box: the outline's and the red
    top's boxes widened by TRACK_GROW_PX (the red top's within the region). ``found``
    must have both outlines (a trackable frame's: its corners were found on them)."""
    if found.outline_rect is None or found.red_rect is None:
        raise ValueError("tracked_boxes: the frame's outline or red top was not found")
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
