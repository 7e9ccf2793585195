"""What the BallTable detector's stages hand each other: the image stage's
:class:`BallTableFeatures` (pixels) and the geometry stage's :class:`BallTableDetection`
(table pose, ball on the table), and the names of the two corner models.

The measurements obs_mode already reports perfect features; :func:`features_from_measurement`
converts them, so the same geometry stage runs on both.
"""

from __future__ import annotations

from dataclasses import Field, dataclass, fields
from typing import Any, ClassVar

import numpy as np

from observer_gym.envs.ball_table.layout import BALL_PX, CORNERS_PX, DETECTED

__all__ = [
    "BORDER_OUTLINE",
    "RED_TOP",
    "BallTableDetection",
    "BallTableFeatures",
    "features_from_measurement",
]

RED_TOP = "red_top"  # corners of the red top: (+-L/2, +-L/2, 0) in the table frame
BORDER_OUTLINE = "border_outline"  # outer top edges of the borders: (+-(L/2 + w), ., h)


class _ComparedByValue:
    """``==`` field by field, arrays by value (a dataclass's own ``==`` fails on arrays,
    and gymnasium's env checker compares the infos an observer puts these in)."""

    __dataclass_fields__: ClassVar[dict[str, Field[Any]]]  # the subclass's @dataclass

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        return all(_same(getattr(self, f.name), getattr(other, f.name)) for f in fields(self))

    __hash__ = None  # type: ignore[assignment]  # mutable arrays inside; typeshed: a method


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
