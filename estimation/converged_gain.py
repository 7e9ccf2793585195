"""The converged-gain path of :class:`~observer_gym.estimation.filters.KalmanFilter`
(switched on by its ``converged_rtol``).

A predict + update cycle with the same ``Phi``, ``Q``, ``C`` and ``R`` objects as the cycle
before (the cached, read-only matrices a
:class:`~observer_gym.estimation.models.LinearModel` hands out) that changes P(k|k) by at
most ``rtol`` times its largest entry has reached the Riccati recursion's fixed point.
:class:`ConvergedGain` then keeps that cycle's P(k|k-1), P(k|k), S, C P C^T and K_f
(:class:`FixedPoint`), and the filter's next cycles only propagate x, (1) and (5) with the
stored K_f, gated with the stored S, as the steady-state filter would. Any other cycle
leaves the path and the filter runs the full recursion until it converges again: a missed
or rejected measurement, other matrices, an R12, or a P assigned from outside (each is
noticed because P is then not the stored array).

A small object the filter owns rather than a subclass: the convergence test needs the
full update's intermediates (P(k|k-1), S, C P C^T, K_f^T), which only
:meth:`KalmanFilter.update <observer_gym.estimation.filters.KalmanFilter.update>` computes,
and any filter takes the path through one constructor argument. This object decides when
the path applies and remembers the fixed point; the filter does the arithmetic. A filter
without it pays one ``is None`` test per step.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ConvergedGain", "FixedPoint"]


@dataclass(frozen=True, slots=True)
class FixedPoint:
    """One converged predict + update cycle: the matrices it ran with (recognised by
    identity) and the covariances and gain it reached."""

    Phi: np.ndarray
    Q: np.ndarray
    C: np.ndarray
    R: np.ndarray
    P_pred: np.ndarray  # P(k|k-1)
    P_filt: np.ndarray  # P(k|k)
    S: np.ndarray  # R2 + C P(k|k-1) C^T
    CPCt: np.ndarray  # C P(k|k-1) C^T
    Kt: np.ndarray  # K_f^T (m, n)


class ConvergedGain:
    """When a :class:`~observer_gym.estimation.filters.KalmanFilter` may skip its Riccati
    recursion, and the fixed point it then uses (see the module docstring).

    ``cycles`` counts the cycles taken on the path (the filter's ``steady_cycles``).
    """

    def __init__(self, rtol: float) -> None:
        self.rtol = rtol
        self.cycles = 0
        self.fixed_point: FixedPoint | None = None
        # (Phi, Q, C, R, P(k|k)) of the last full cycle, for the convergence test; the
        # (Phi, Q) of the last full predict; whether the last predict was on the path.
        self._last_cycle: tuple[np.ndarray, ...] | None = None
        self._last_predict: tuple[np.ndarray, np.ndarray] | None = None
        self._predicted = False

    def predicted_covariance(
        self, Phi: np.ndarray, Q: np.ndarray, P_filt: np.ndarray, plain: bool
    ) -> np.ndarray | None:
        """P(k+1|k) of the fixed point when this predict repeats its ``Phi`` and ``Q`` from
        its P(k|k) and is ``plain`` (no R12 effect pending). Else None: the path is left
        and the filter runs the full predict."""
        fixed = self.fixed_point
        if (
            fixed is not None
            and Phi is fixed.Phi
            and Q is fixed.Q
            and P_filt is fixed.P_filt
            and plain
        ):
            self._predicted = True
            return fixed.P_pred
        self.fixed_point = None
        self._predicted = False
        self._last_predict = (Phi, Q)
        return None

    def fixed_point_for(
        self, C: np.ndarray, R: np.ndarray, R12: np.ndarray | None, P_pred: np.ndarray
    ) -> FixedPoint | None:
        """The fixed point when this update follows a predict on the path with its ``C``
        and ``R``, no ``R12``, and its P(k|k-1); else None: the filter runs the full
        update."""
        if not self._predicted:
            return None
        self._predicted = False
        fixed = self.fixed_point
        assert fixed is not None  # a predict on the path had it
        if C is fixed.C and R is fixed.R and R12 is None and P_pred is fixed.P_pred:
            return fixed
        return None

    def no_riccati_step(self) -> None:
        """A missed measurement, or one the full update's gate rejected: this cycle does
        not count toward convergence."""
        self._last_cycle = None

    def leave(self) -> None:
        """A measurement rejected on the path: the next cycle runs the full recursion."""
        self.fixed_point = self._last_cycle = None

    def full_update_done(
        self,
        C: np.ndarray,
        R: np.ndarray,
        P_pred: np.ndarray,
        P_filt: np.ndarray,
        S: np.ndarray,
        CPCt: np.ndarray,
        Kt: np.ndarray,
        plain: bool,
    ) -> None:
        """After a full update (``plain``: no R12 now or pending): enter the path if this
        cycle repeated the last one's matrices and moved P(k|k) by at most ``rtol`` times
        its largest entry."""
        last, predicted = self._last_cycle, self._last_predict
        self._last_predict = None
        if predicted is None or not plain:
            self._last_cycle = None  # not a plain predict + update cycle
            return
        Phi, Q = predicted
        self._last_cycle = (Phi, Q, C, R, P_filt)
        if last is None or not (last[0] is Phi and last[1] is Q and last[2] is C and last[3] is R):
            return
        change = np.abs(P_filt - last[4]).max()
        if change <= self.rtol * np.abs(P_filt).max():
            self.fixed_point = FixedPoint(
                Phi, Q, C, R, P_pred, P_filt, S.copy(), CPCt.copy(), Kt.copy()
            )
