"""The stationary Kalman filter of an LTI model: its gain from the filter DARE, and a
fixed-gain filter that runs (1) and (5) with it.

Notation and equation numbers as in :mod:`observer_gym.estimation.filters`
(docs/spec/catcher.md, Linderoth et al., ICRA 2010).
"""

from __future__ import annotations

import numpy as np

from observer_gym.estimation.covariance import right_divide, symmetrised

__all__ = ["SteadyStateKalmanFilter", "steady_state_gain"]


def steady_state_gain(
    Phi: np.ndarray,
    C: np.ndarray,
    Q: np.ndarray,
    R: np.ndarray,
    R12: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Stationary filter gain K_f (n, m) and prediction covariance P = P(k+1|k) (n, n).

    P solves the filter DARE, the stationary form of (10):

        Phi P Phi^T - P - (Phi P C^T + R12) (C P C^T + R)^-1 (C P Phi^T + R12^T) + Q = 0,

    which is python-control's ``dare(A, B, Q, R, S)`` (A^T X A - X - (A^T X B + S)
    (B^T X B + R)^-1 (B^T X A + S^T) + Q = 0) for the dual system A = Phi^T, B = C^T,
    S = R12. The filter gain is K_f = P C^T (C P C^T + R)^-1 (6); the predictor gain (9)
    is Phi K_f + R12 (C P C^T + R)^-1.
    """
    import control  # imported on use: python-control loads matplotlib (~0.7 s)

    Phi, C = np.asarray(Phi, dtype=float), np.asarray(C, dtype=float)
    Q, R = np.asarray(Q, dtype=float), np.asarray(R, dtype=float)
    S = None if R12 is None else np.asarray(R12, dtype=float)
    P, _, _ = control.dare(Phi.T, C.T, Q, R, S, method="scipy")
    P = symmetrised(np.asarray(P, dtype=float))
    K = right_divide(np.dot(P, C.T), np.dot(np.dot(C, P), C.T) + R)  # (6)
    return K, P


class SteadyStateKalmanFilter:
    """Fixed-gain Kalman filter for an LTI model: (1) and (5) with a constant K_f.

    Preallocated buffers, in-place updates: ``x`` is modified in place at every step
    (copy it to keep it). ``P_pred`` and ``P_filt`` are the stationary covariances, valid
    while a measurement arrives every step.
    """

    def __init__(
        self,
        x0: np.ndarray,
        gain: np.ndarray,
        C: np.ndarray,
        P_pred: np.ndarray | None = None,
    ) -> None:
        self.x = np.array(x0, dtype=float).reshape(-1)
        self.gain = np.array(gain, dtype=float)
        self.C = np.array(C, dtype=float)
        n, m = self.x.shape[0], self.C.shape[0]
        if self.gain.shape != (n, m) or self.C.shape != (m, n):
            raise ValueError(
                f"SteadyStateKalmanFilter: gain {self.gain.shape} and C {self.C.shape} "
                f"must be {(n, m)} and {(m, n)}"
            )
        self.P_pred = P_pred
        self.P_filt = None
        if P_pred is not None:
            A = np.eye(n) - np.dot(self.gain, self.C)
            self.P_filt = symmetrised(np.dot(A, P_pred))  # (7)
        self._x_spare = np.empty(n)  # predict() writes here, then swaps it with x
        self._x_step = np.empty(n)
        self._gamma_u = np.empty(n)
        self._innovation = np.empty(m)

    @classmethod
    def from_model(
        cls, x0: np.ndarray, Phi: np.ndarray, C: np.ndarray, Q: np.ndarray, R: np.ndarray
    ) -> SteadyStateKalmanFilter:
        """Gain from :func:`steady_state_gain` for the model (Phi, C, Q, R)."""
        K, P_pred = steady_state_gain(Phi, C, Q, R)
        return cls(x0, K, C, P_pred)

    def predict(
        self, Phi: np.ndarray, Gamma: np.ndarray | None = None, u: np.ndarray | None = None
    ) -> None:
        """x <- Phi x + Gamma u (1)."""
        x_next = self._x_spare
        Phi.dot(self.x, x_next)
        if Gamma is not None:
            assert u is not None, "give u with Gamma"
            x_next += Gamma.dot(u, self._gamma_u)
        self._x_spare = self.x
        self.x = x_next

    def update(self, y: np.ndarray | None) -> None:
        """x <- x + K_f (y - C x) (5); y None (missed) leaves x unchanged."""
        if y is None:
            return
        d = self._innovation
        np.subtract(y, self.C.dot(self.x, d), out=d)
        self.x += self.gain.dot(d, self._x_step)
