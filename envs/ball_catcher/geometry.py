"""BallCatcher geometry: the rig's layout, the box, the cameras (docs/spec/catcher.md).

World frame: z up, the arm's base at the origin, the thrower on the +x side. The box's
front face (with the hole) always faces +x, toward the thrower; the box frame has its
origin at the hole's centre on the front face's outer plane and its z axis along the
outward normal (+x world), so the box body is welded to the flange with no rotation
(the flange's z axis points at the thrower).
"""

from __future__ import annotations

import numpy as np

from observer_gym.envs.camera import look_at

BALL_RADIUS_M = 0.025  # spec: ball diameter 5 cm
HOLE_DIAMETER_M = 0.06  # spec: hole diameter 6 cm (configurable)

# The box (metres): a square front face with the hole, walls WALL_M thick.
BOX_OUTER_SIDE_M = 0.18  # front face side
BOX_DEPTH_M = 0.16  # front face's outer plane to the back wall's outer plane
WALL_M = 0.01
HOLE_SEGMENTS = 24  # the round hole's rim is a ring of this many boxes (see scene.py)

ARM_BASE_WORLD = np.zeros(3)
# Flange orientation: z along +x world (toward the thrower), x down: R_y(+90 deg).
FLANGE_QUAT_WORLD = (0.0, float(np.sin(np.pi / 4)), 0.0, float(np.cos(np.pi / 4)))
NORMAL_WORLD = np.array([1.0, 0.0, 0.0])  # the front face's outward normal
# Where the box's back wall meets the flange: the hole centre is this far ahead of it.
FLANGE_TO_HOLE_M = BOX_DEPTH_M

# The hole centre's home and the box it may move in (checked reachable with the flange
# horizontal by tests/envs/test_ball_catcher.py). At this height the arm stays well away
# from its singular postures: the smallest singular value of the flange's 6x7 Jacobian is
# 0.16-0.21 at home and >= 0.15 across the workspace, where at a home 0.2 m higher it is
# 0.05 and a 7 cm sideways move swings joints 1, 3, 5 and 7 through a radian.
HOLE_HOME_WORLD = np.array([0.70, 0.0, 0.50])
WORKSPACE_LOW_WORLD = np.array([0.65, -0.30, 0.35])
WORKSPACE_HIGH_WORLD = np.array([0.75, 0.30, 0.65])
# Joint angles near the home pose (refined by IK at the first build).
ARM_HOME_Q = (0.0, 0.45, 0.0, -1.93, 0.0, -0.81, 0.0)

# Miss: the ball's centre below this height (it fell past the box) ends the episode.
MISS_HEIGHT_M = 0.15

# Camera rig: up to four cameras (eye, the point the optical axis goes through), world
# frame. Camera 0 stands beside the flight path and camera 1 above and behind the robot,
# so that near the box their viewlines cross at about 90 deg and camera 1 sees the box's
# plane nearly face-on (a facing pair, one on each side of the path, would leave the
# crossing's y along both cameras' depth: measured 1.5x the crossing error). Camera 0
# alone is the "single" preset (alone, the side view caught more throws than the view
# from behind: 10 / 60 against 4 / 60). Cameras 2 and 3 add a view from the other side
# and one from above the thrower.
CAMERA_RIG_WORLD = (
    (np.array([1.1, -1.5, 0.9]), np.array([1.7, 0.0, 0.65])),
    (np.array([-0.4, 0.6, 1.4]), np.array([1.9, 0.0, 0.6])),
    (np.array([1.1, 1.5, 0.9]), np.array([1.7, 0.0, 0.65])),
    (np.array([3.7, 0.8, 1.8]), np.array([1.3, 0.0, 0.6])),
)
MAX_CAMERAS = len(CAMERA_RIG_WORLD)


def camera_pose(index: int) -> np.ndarray:
    """``T_world_cam`` of rig camera ``index`` (0 to MAX_CAMERAS - 1)."""
    eye, target = CAMERA_RIG_WORLD[index]
    return look_at(eye, target)


# --- the catch rule (box frame: origin at the hole's centre on the front plane, z outward) ---
def clean_radius_m(hole_diameter_m: float) -> float:
    """How far from the hole's axis the ball's centre may cross the front plane and the
    ball still clear the hole's circle: the hole's radius minus the ball's."""
    return hole_diameter_m / 2 - BALL_RADIUS_M


def front_plane_entry(p0_box, p1_box) -> np.ndarray | None:
    """Where the ball's centre, moving from ``p0_box`` to ``p1_box`` (box frame) in one
    physics step, crosses the front plane inward (z from >= 0 to < 0), linearly
    interpolated; None if it does not."""
    p0, p1 = np.asarray(p0_box, dtype=float), np.asarray(p1_box, dtype=float)
    if not (p0[2] >= 0.0 > p1[2]):
        return None
    return p0 + (p0[2] / (p0[2] - p1[2])) * (p1 - p0)


def approach_point(p_box, v_box) -> np.ndarray | None:
    """Where the ball's centre at ``p_box`` moving at ``v_box`` (box frame, relative to the
    box) would cross the front plane inward flying straight on; None if it is behind
    the plane or not approaching it."""
    p, v = np.asarray(p_box, dtype=float), np.asarray(v_box, dtype=float)
    if p[2] < 0.0 or not v[2] < 0.0:
        return None
    return p - (p[2] / v[2]) * v


def on_front_face(point_box) -> bool:
    """Whether a point of the front plane (box frame) is on the box's front face."""
    return bool(max(abs(point_box[0]), abs(point_box[1])) < BOX_OUTER_SIDE_M / 2)


def is_clean(point_box, hole_diameter_m: float) -> bool:
    """Whether the ball's centre crossing the front plane at ``point_box`` clears the hole."""
    return bool(np.hypot(point_box[0], point_box[1]) < clean_radius_m(hole_diameter_m))
