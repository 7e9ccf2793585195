"""Quadratic cost weights: the checks every weighted design runs, and BallTable's defaults."""

from __future__ import annotations

import numpy as np

__all__ = ["ball_table_weights", "check_weights"]


def _as_matrix(name: str, value, size: int) -> np.ndarray:
    M = np.array(value, dtype=float)
    if M.ndim == 1:  # a diagonal
        M = np.diag(M)
    if M.shape != (size, size):
        raise ValueError(
            f"{name} has shape {M.shape}, expected ({size}, {size}) or its diagonal ({size},)"
        )
    if not np.all(np.isfinite(M)):
        raise ValueError(f"{name} has non-finite entries: {M.tolist()}")
    scale = max(float(np.abs(M).max()), 1.0)
    if not np.allclose(M, M.T, rtol=0.0, atol=1e-12 * scale):
        raise ValueError(f"{name} must be symmetric, got {M.tolist()}")
    return 0.5 * (M + M.T)


def check_weights(Q, R, n: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """(Q, R) as symmetric float matrices, or ``ValueError`` naming the problem.

    Q (n, n) must be positive semidefinite, R (m, m) positive definite; either may be
    given as its diagonal.
    """
    Q = _as_matrix("Q", Q, n)
    R = _as_matrix("R", R, m)
    q_min = float(np.linalg.eigvalsh(Q).min())
    if q_min < -1e-12 * max(float(np.abs(Q).max()), 1.0):
        raise ValueError(f"Q must be positive semidefinite; its smallest eigenvalue is {q_min:g}")
    r_min = float(np.linalg.eigvalsh(R).min())
    if r_min <= 0.0:
        raise ValueError(f"R must be positive definite; its smallest eigenvalue is {r_min:g}")
    return Q, R


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
