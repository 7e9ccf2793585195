"""Observation layouts of BallTable-v0, defined once and exported.

``obs_mode="state"`` (and ``info["state"]``, and the observer's estimate) is a float vector
with the entries STATE_NAMES, indexed by :class:`StateIndex`. Ball position and velocity
are in the table frame TRF (velocity relative to the table); tilt angles follow
:mod:`observer_gym.envs.ball_table.geometry`.

``obs_mode="measurements"`` is a Dict with the keys below: what a perfect detector reports
for the latest frame, in pixels (OpenCV convention), without rendering.
"""

from __future__ import annotations

from enum import IntEnum

STATE_NAMES = (
    "ball_x_m",
    "ball_y_m",
    "ball_vx_mps",
    "ball_vy_mps",
    "tilt_x_rad",
    "tilt_y_rad",
    "tilt_rate_x_radps",
    "tilt_rate_y_radps",
)


class StateIndex(IntEnum):
    BALL_X = 0
    BALL_Y = 1
    BALL_VX = 2
    BALL_VY = 3
    TILT_X = 4
    TILT_Y = 5
    TILT_RATE_X = 6
    TILT_RATE_Y = 7


STATE_DIM = len(STATE_NAMES)
BALL_POS = slice(StateIndex.BALL_X, StateIndex.BALL_Y + 1)
BALL_VEL = slice(StateIndex.BALL_VX, StateIndex.BALL_VY + 1)
TILT = slice(StateIndex.TILT_X, StateIndex.TILT_Y + 1)
TILT_RATE = slice(StateIndex.TILT_RATE_X, StateIndex.TILT_RATE_Y + 1)

# Bounds of the state observation (the env clips the observation to them; info["state"]
# is never clipped). The ball leaving the table ends the episode long before these.
STATE_HIGH = (1.0, 1.0, 10.0, 10.0, 1.5, 1.5, 20.0, 20.0)

# Measurement keys.
# (8,): u0, v0, ..., u3, v3 of the red top's corners, in TABLE_CORNERS_TABLE order
CORNERS_PX = "table_corners_px"
BALL_PX = "ball_px"  # (3,): u, v of the ball image's centre, and its semi-major axis
DETECTED = "detected"  # (2,) MultiBinary: [table found, ball found]
