"""Self-tuning measurement covariance (docs/spec/follower.md (35)-(41), Tsai et al. 2009).

For each measured channel keep the last k observations Y = (y_1 .. y_k) in a shift
register. Fitting a line y_n = a n + b by least squares, with the fixed regressor
A = [[1, 1], [2, 1], ..., [k, 1]], leaves the residual of least variance

    eps* = T_st Y,   T_st = I_k - A (A^T A)^-1 A^T                        (35)-(40)

(T_st projects onto the orthogonal complement of the lines, so a straight-line signal
leaves no residual and the measurement noise is what remains). Its variance per channel
is sigma^2 = var(eps*) = eps*^T eps* / k, the variance of the k residuals as the spec
writes it (their mean is zero: the fit has an intercept). For white noise of variance
s^2 its expectation is (k - 2) s^2 / k; the Table 2 study (train/experiments/reproduce/tsai2009.py)
matched the paper's figures better with this than with the unbiased eps*^T eps* / (k - 2)
(at sigma_n = 10, x_i: 17.1 against 21.7 px^2). The measurement covariance is then

    R_n = R_0 + diag((sigma_1^2)^2, ..., (sigma_m^2)^2)                        (41)

The spec squares the variance (its units are then px^4, not px^2), and so do we: that is
the published rule, and it is what makes R grow fast with the noise level and the filter
lean on its model (Table 2). Until the register is full, R_n = R_0.
"""

from __future__ import annotations

from collections import deque

import numpy as np

__all__ = ["SelfTuningR", "line_residual_projector"]


def line_residual_projector(k: int) -> np.ndarray:
    """T_st = I_k - A (A^T A)^-1 A^T with A = [[1, 1], ..., [k, 1]] (35)-(40)."""
    if k < 3:
        raise ValueError(f"line_residual_projector: k = {k!r}, needs k >= 3 (a line has 2 dof)")
    A = np.column_stack([np.arange(1.0, k + 1.0), np.ones(k)])
    T_st = np.eye(k) - A @ np.linalg.solve(A.T @ A, A.T)
    T_st.flags.writeable = False
    return T_st


class SelfTuningR:
    """The shift register and R update of the self-tuning Kalman filter.

    Args:
        R0: the base covariance R_0 (m, m).
        window: k, the number of observations per channel in the register (>= 3).
    """

    def __init__(self, R0: np.ndarray, window: int) -> None:
        self.R0 = np.array(R0, dtype=float)
        m = self.R0.shape[0]
        if self.R0.shape != (m, m):
            raise ValueError(f"SelfTuningR: R0 has shape {self.R0.shape}, must be square")
        self.window = int(window)
        self.T_st = line_residual_projector(self.window)
        self._register: deque[np.ndarray] = deque(maxlen=self.window)
        self._m = m

    def reset(self) -> None:
        """Empty the register (R_n = R_0 until it is full again)."""
        self._register.clear()

    @property
    def full(self) -> bool:
        return len(self._register) == self.window

    @property
    def samples(self) -> tuple[np.ndarray, ...]:
        """The register's observations, oldest first (a snapshot: see :meth:`refill`)."""
        return tuple(self._register)

    def refill(self, samples: tuple[np.ndarray, ...]) -> None:
        """Put the register back to ``samples`` (from :attr:`samples`)."""
        self.reset()
        for z in samples:
            self.push(z)

    def push(self, z: np.ndarray) -> None:
        """Shift the observation z (m,) into the register (the oldest drops out)."""
        z = np.asarray(z, dtype=float).reshape(-1)
        if z.shape != (self._m,):
            raise ValueError(f"SelfTuningR.push: z has shape {z.shape}, expected ({self._m},)")
        self._register.append(z)

    def residual_variance(self) -> np.ndarray:
        """sigma^2 per channel, var(eps*) = eps*^T eps* / k with eps* = T_st Y (35)-(40);
        zeros while the register is not full."""
        if not self.full:
            return np.zeros(self._m)
        Y = np.array(self._register)  # (k, m): one column per channel
        eps = self.T_st @ Y
        return np.einsum("ij,ij->j", eps, eps) / self.window  # var(eps*): its mean is 0

    def R(self) -> np.ndarray:
        """R_n = R_0 + diag((sigma^2)^2) (41) when the register is full, else R_0."""
        if not self.full:
            return self.R0.copy()
        return self.R0 + np.diag(self.residual_variance() ** 2)  # (41): variance squared
