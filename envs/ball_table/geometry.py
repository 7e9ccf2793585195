"""BallTable geometry and the tilt convention (docs/spec/table_ball.md, "Scene and camera").

Table frame TRF: origin at the centre of the red top surface, z up out of it, x and y
along its edges; the corners are (+-L/2, +-L/2, 0). At the home pose TRF is parallel to
the world frame.

Tilt angles: the table's orientation relative to its home pose is
R_home_table = R_x(tilt_x) @ R_y(tilt_y). The world's up axis in the table frame is then
Z_gnd,table = (-sin(tilt_y) cos(tilt_x), sin(tilt_x), cos(tilt_y) cos(tilt_x)), and a
ball rolling without slipping accelerates as a = -(5/7) g Z_gnd,table[x, y]:
a_x = (5/7) g sin(tilt_y) cos(tilt_x), a_y = -(5/7) g sin(tilt_x) (spec: "A solid ball
rolling without slipping ... a = (5/7) g sin(theta)"; the ball goes to the lower side).
"""

from __future__ import annotations

import math

import numpy as np

from observer_gym.envs.transforms import rot_x, rot_y

TABLE_SIDE_M = 0.30  # L, the red top's side
BALL_RADIUS_M = 0.025  # r
BORDER_WIDTH_M = 0.01  # black borders stand just outside the red square
BORDER_HEIGHT_M = 0.03  # above the top surface; > r, so the ball stops at L/2 - r
BALL_TRAVEL_M = TABLE_SIDE_M / 2 - BALL_RADIUS_M  # |x|, |y| of the ball centre at a border

# The red top's corners in TRF, in this fixed order.
TABLE_CORNERS_TABLE = (TABLE_SIDE_M / 2) * np.array(
    [[1.0, 1.0, 0.0], [-1.0, 1.0, 0.0], [-1.0, -1.0, 0.0], [1.0, -1.0, 0.0]]
)

# Scene layout (world frame, metres). The arm's base is at the origin; its flange holds
# the table's centre TABLE_CENTRE_HOME_WORLD with the flange axis vertical.
ARM_BASE_WORLD = np.zeros(3)
FLANGE_TO_TABLE_M = 0.055  # flange frame origin to the table top along the flange axis
TABLE_CENTRE_HOME_WORLD = np.array([0.60, 0.0, 0.90 + FLANGE_TO_TABLE_M])
# Joint angles near the home pose, 0.77 rad or more inside every joint limit; refined by IK.
ARM_HOME_Q = (0.0, 0.528, 0.0, -0.799, 0.0, -1.328, 0.0)

# The robot's eye: above the table, 0.10 m toward the arm's base, looking at its centre.
# From inside the table's footprint the raised borders never hide the red top.
CAMERA_EYE_WORLD = TABLE_CENTRE_HOME_WORLD + np.array([-0.10, 0.0, 0.40])

# The occluder: a grey slab (assets/occluder.urdf) that crosses between camera and table.
OCCLUDER_HALF_EXTENTS_M = np.array([0.25, 0.04, 0.005])
OCCLUDER_HEIGHT_M = 0.2  # above the table's centre, halfway to the camera


def tilt_rotation(tilt_x: float, tilt_y: float) -> np.ndarray:
    """R_home_table for the given tilt angles (rad)."""
    return rot_x(tilt_x) @ rot_y(tilt_y)


def tilt_angles(R_home_table: np.ndarray) -> tuple[float, float]:
    """Inverse of :func:`tilt_rotation` (ignoring any residual yaw). Plain floats: it runs
    in every env step and every detection, where NumPy's scalar calls cost more."""
    (_, _, r02), (_, _, r12), (_, _, r22) = R_home_table.tolist()
    return math.atan2(-r12, r22), math.asin(min(max(r02, -1.0), 1.0))


def tilt_rates(omega_table: np.ndarray, tilt_y: float) -> tuple[float, float]:
    """d/dt (tilt_x, tilt_y) from the table's angular velocity in its own frame.

    With R = R_x(a) R_y(b) the body angular velocity is (cos(b) da, db, sin(b) da).
    """
    return float(omega_table[0] / np.cos(tilt_y)), float(omega_table[1])


def up_in_table(tilt_x: float, tilt_y: float) -> np.ndarray:
    """Z_gnd,table: the world's up axis in the table frame (spec, "Dynamics"), the third
    row of R_x(tilt_x) R_y(tilt_y): (-sin(tilt_y) cos(tilt_x), sin(tilt_x),
    cos(tilt_y) cos(tilt_x))."""
    cx, sx = math.cos(tilt_x), math.sin(tilt_x)
    cy, sy = math.cos(tilt_y), math.sin(tilt_y)
    return np.array([-sy * cx, sx, cy * cx])
