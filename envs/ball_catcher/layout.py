"""The BallCatcher state layout: what ``obs_mode="state"`` returns and an observer estimates.

World frame (z up, the thrower on the +x side), metres and metres per second. The box's
position is its hole's centre on the front face's outer plane.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np


class StateIndex(IntEnum):
    BALL_X = 0
    BALL_Y = 1
    BALL_Z = 2
    BALL_VX = 3
    BALL_VY = 4
    BALL_VZ = 5
    BOX_X = 6
    BOX_Y = 7
    BOX_Z = 8
    BOX_VX = 9
    BOX_VY = 10
    BOX_VZ = 11


# Names with their units, as the other envs' layouts: "ball_x_m", "ball_vx_mps", ...
STATE_NAMES = tuple(f"{i.name.lower()}_{'mps' if '_V' in i.name else 'm'}" for i in StateIndex)
STATE_DIM = len(STATE_NAMES)
BALL_POS = slice(0, 3)
BALL_VEL = slice(3, 6)
BALL = slice(0, 6)
BOX_POS = slice(6, 9)
BOX_VEL = slice(9, 12)
BOX = slice(6, 12)

# Bounds of the observation Box: positions within 10 m, speeds within 30 m/s.
STATE_HIGH = np.array([10.0] * 3 + [30.0] * 3 + [10.0] * 3 + [30.0] * 3)
