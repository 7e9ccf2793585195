"""Quadratic cost weights: the checks every weighted design runs."""

from __future__ import annotations

import numpy as np

__all__ = ["check_weights"]


def _as_matrix(name: str, value, size: int) -> np.ndarray:
    try:
        M = np.array(value, dtype=float)
    except (TypeError, ValueError, OverflowError):  # OverflowError: an int beyond a float
        raise ValueError(
            f"{name} = {value!r:.200}, must be a ({size}, {size}) matrix of numbers or its diagonal"
        ) from None
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
