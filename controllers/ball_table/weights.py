"""BallTable's default LQR/MPC weights (Bryson's rule)."""

from __future__ import annotations

import numpy as np

__all__ = ["ball_table_weights"]

# Bryson's rule: each weight is 1 / (acceptable value)^2.
BALL_POS_SCALE_M = 0.01
BALL_VEL_SCALE_MPS = 0.1
TILT_SCALE_RAD = 0.1
# The command's scale sets the loop gain. At 0.1 rad (the env's tilt bound) and at
# 0.058 rad even the oracle LQR loop falls into a 6-7 mm limit cycle with the command
# saturated most of the time: the real plant's extra lag and the table's rotation terms,
# which the nominal model leaves out, eat the phase margin. At 0.03 rad the oracle loop
# settles, but through the pixel observer one start in eight keeps a 3 mm, 6 Hz
# oscillation. At 0.02 rad all eight stay within 0.7 mm of the centre after 4 s, at the
# price of ~5 % more mean distance while settling (``observer-gym run``).
COMMAND_SCALE_RAD = 0.02


def ball_table_weights() -> tuple[np.ndarray, np.ndarray]:
    """Default (Q, R) for the 6-state BallTable control model (Bryson's rule): 1 cm of
    ball offset weighs as much as 10 cm/s of speed, 0.1 rad of table tilt or a 0.02 rad
    command."""
    Q = np.diag(
        [BALL_POS_SCALE_M**-2] * 2 + [BALL_VEL_SCALE_MPS**-2] * 2 + [TILT_SCALE_RAD**-2] * 2
    )
    R = np.eye(2) * COMMAND_SCALE_RAD**-2
    return Q, R
