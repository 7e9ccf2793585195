"""BallCatcher geometry: the rig's layout, the box, the cameras (spec/catcher.md).

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
# horizontal by tests/envs/test_ball_catcher.py). Commands that would leave it are stopped
# at its faces.
HOLE_HOME_WORLD = np.array([0.60, 0.0, 0.70])
WORKSPACE_LOW_WORLD = np.array([0.55, -0.30, 0.50])
WORKSPACE_HIGH_WORLD = np.array([0.65, 0.30, 0.90])
# Joint angles near the home pose (refined by IK at the first build).
ARM_HOME_Q = (0.0, 0.5, 0.0, -1.2, 0.0, 0.9, 0.0)

# Miss: the ball's centre below this height (it fell past the box) ends the episode.
MISS_HEIGHT_M = 0.30

# Camera rig: up to four cameras beside the flight path, watching the region between the
# thrower and the box (T_world_cam from look_at: OpenCV axes). Camera 0 and 1 are the
# default pair: left and right of the flight, 2 m out, so their viewlines cross at about
# 90 deg over the box.
CAMERA_TARGET_WORLD = np.array([1.8, 0.0, 1.0])
CAMERA_EYES_WORLD = (
    np.array([1.2, -2.0, 1.4]),
    np.array([1.2, 2.0, 1.4]),
    np.array([-0.6, -1.0, 1.8]),
    np.array([-0.6, 1.0, 1.8]),
)
MAX_CAMERAS = len(CAMERA_EYES_WORLD)


def camera_pose(index: int) -> np.ndarray:
    """``T_world_cam`` of rig camera ``index`` (0 to MAX_CAMERAS - 1)."""
    return look_at(CAMERA_EYES_WORLD[index], CAMERA_TARGET_WORLD)
