"""The extended Kalman filter: a nonlinear process x(k+1) = f(x(k)) and measurement
y = h(x) + e, linearised at the current estimate, on the linear filter's core.

    predict:  x <- f(x),                P <- F P F^T + Q,        F = df/dx at x
    update:   d = y - h(x),  S = H P H^T + R,  K = P H^T S^-1,  H = dh/dx at x(k|k-1)
              x <- x + K d,  P <- (I - K H) P (I - K H)^T + K R K^T   (Joseph form)

The update is :meth:`KalmanFilter.update` with C = H and the pseudo-measurement
y' = y - h(x) + H x, whose innovation y' - H x is the EKF's d, so gating, the Joseph
form and the positive-definite repair are the linear filter's. On a linear model
(f(x) = Phi x, h(x) = C x) every step is the linear filter's to rounding, which
tests/estimation/test_ekf.py checks. Hand-written on that core rather than filterpy's
ExtendedKalmanFilter: that has no gating and no Joseph-form repair, and keeps no
missed-measurement convention of ours (``update(None)``).

Jacobians are the caller's (analytic where the model gives them) or
:func:`numerical_jacobian`'s central differences.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from observer_gym.estimation.filters import KalmanFilter, UpdateResult

__all__ = ["ExtendedKalmanFilter", "numerical_jacobian"]


def numerical_jacobian(
    fn: Callable[[np.ndarray], np.ndarray], x: np.ndarray, step: np.ndarray | float = 1e-6
) -> np.ndarray:
    """d fn / dx at ``x`` by central differences (m, n): column j is
    (fn(x + h e_j) - fn(x - h e_j)) / 2h. No truncation error for an affine ``fn``,
    only rounding, of order 1e-16 |fn(x)| / h; ``step`` h (scalar or per coordinate) is
    in the units of x."""
    x = np.asarray(x, dtype=float)
    steps = np.broadcast_to(np.asarray(step, dtype=float), x.shape)
    columns = []
    for j, h in enumerate(steps):
        dx = np.zeros_like(x)
        dx[j] = h
        columns.append((np.asarray(fn(x + dx)) - np.asarray(fn(x - dx))) / (2.0 * h))
    return np.column_stack(columns)


class ExtendedKalmanFilter(KalmanFilter):
    """EKF on :class:`~observer_gym.estimation.filters.KalmanFilter` (see the module
    docstring). ``gate`` and the constructor's other arguments are the linear filter's;
    the converged-gain path is off (the Jacobians change every step)."""

    def __init__(self, x0: np.ndarray, P0: np.ndarray, gate=None) -> None:
        super().__init__(x0, P0, gate=gate, converged_rtol=None)

    def predict_nonlinear(self, x_next: np.ndarray, F: np.ndarray, Q: np.ndarray) -> None:
        """x <- ``x_next`` (f(x), computed by the caller), P <- F P F^T + Q."""
        x_next = np.asarray(x_next, dtype=float).reshape(-1)
        if x_next.shape != (self.dim_x,):
            raise ValueError(
                f"ExtendedKalmanFilter: f(x) has shape {x_next.shape}, expected ({self.dim_x},)"
            )
        # P <- F P F^T + Q (the linear predict with Phi = F); then x is replaced by f(x).
        self.predict(np.asarray(F, dtype=float), np.asarray(Q, dtype=float))
        self.x = x_next.copy()

    def update_nonlinear(
        self, y: np.ndarray | None, h_x: np.ndarray, H: np.ndarray, R: np.ndarray
    ) -> UpdateResult:
        """Measurement update with the predicted measurement ``h_x`` = h(x) and its Jacobian
        ``H`` at x; ``y`` None is a missed measurement (x and P unchanged)."""
        if y is None:
            return self.update(None, H, R)
        H = np.asarray(H, dtype=float)
        # y' = y - h(x) + H x: the linear update's innovation y' - H x is y - h(x).
        y_lin = np.asarray(y, dtype=float) - np.asarray(h_x, dtype=float) + H.dot(self.x)
        return self.update(y_lin, H, np.asarray(R, dtype=float))
