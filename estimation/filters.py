"""The time-varying linear Kalman filter: time-varying C, variable measurement size, missed
measurements (``update(None, ...)``, as in filterpy), Joseph-form updates and the
cross-covariance R12.

Notation follows docs/spec/catcher.md (Linderoth et al., ICRA 2010); equation numbers in
brackets are that paper's:

    x(k+1) = Phi x(k) + Gamma u(k) + v(k),   y(k) = C(k) x(k) + e(k)          (1)(2)
    E[v v^T] = R1 (here ``Q``), E[e e^T] = R2 (here ``R``), E[v e^T] = R12     (3)

Filter form (5)-(7) lives in :class:`KalmanFilter`, the one-step predictor form (8)-(10)
in :func:`predictor_step`. Around them: the outlier gates, (27)-(30) among them, in
:mod:`~observer_gym.estimation.gating`; the filter's converged-gain path in
:mod:`~observer_gym.estimation.converged_gain`; the stationary gain and the fixed-gain
filter in :mod:`~observer_gym.estimation.steady_state`; symmetrising and repairing
covariances in :mod:`~observer_gym.estimation.covariance`.

Innovation covariances S are Cholesky-factored and solved, never inverted, except for
m = 1 and m = 2 (one camera point), which use the closed forms 1/s and adj(S)/det(S):
exact to rounding for a 2x2 SPD matrix and ~10x cheaper than a LAPACK call at this size.
Hand-written rather than filterpy's KalmanFilter: that has no R12 and no gating, does
not symmetrise P or keep it positive definite, and is slower here
(benchmarks/bench_filters.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
from scipy.linalg.lapack import dpotrf

from observer_gym.estimation.converged_gain import ConvergedGain, FixedPoint
from observer_gym.estimation.covariance import (
    HALF,
    SYRK_IS_SYMMETRIC,
    is_positive_definite,
    repaired,
    right_divide,
    symmetrised,
)
from observer_gym.estimation.gating import Gate, nis

__all__ = ["KalmanFilter", "UpdateResult", "predictor_step"]


@dataclass(slots=True)
class UpdateResult:
    """What one :meth:`KalmanFilter.update` did.

    ``accepted`` is False for a missed measurement (y None: all other fields None/NaN) and
    for one the gate rejected (innovation, S and NIS are reported, gain is None).
    """

    accepted: bool
    innovation: np.ndarray | None
    innovation_cov: np.ndarray | None
    nis: float
    gain: np.ndarray | None

    @property
    def missed(self) -> bool:
        """True when there was no measurement (y None)."""
        return self.innovation is None


class KalmanFilter:
    """Linear Kalman filter, filter form (5)-(7) with a Joseph-form covariance update.

    ``x`` (n,) and ``P`` (n, n) hold the current estimate: x(k|k), P(k|k) after
    :meth:`update`, x(k+1|k), P(k+1|k) after :meth:`predict`. Each step assigns fresh
    arrays (never writes into the old ones), so references kept from earlier steps stay
    valid; to change them, assign new arrays. Matrix arguments must be float
    ``numpy.ndarray``s: the hot path calls ``ndarray.dot`` (a third cheaper than ``np.dot``
    at this size) and reuses private scratch buffers (benchmarks/bench_filters.py).

    ``gate`` is None or an object with ``accepts(innovation, S, R, CPCt) -> bool``
    (:class:`~observer_gym.estimation.gating.PSigmaGate`,
    :class:`~observer_gym.estimation.gating.ChiSquareGate`); a rejected measurement leaves x and P
    unchanged and increments ``rejected_count``; used ones increment ``accepted_count``.

    P is symmetrised after every step: (P + P^T) / 2 after predict; after update (the step
    that subtracts) P = U^T U with U the Cholesky factor (LAPACK dpotrf) of the Joseph
    product's upper triangle, which symmetrises it exactly and proves it positive definite
    in one factorisation, cheaper than averaging and checking apart. If rounding has made
    it indefinite (only when its eigenvalues span more than double precision resolves,
    e.g. P0 = 1e12 I updated with R = 1e-12 I), it is repaired at the precision floor
    (:func:`~observer_gym.estimation.covariance.repaired`) and ``pd_repairs`` counts it.
    predict adds Q >= 0 to the congruence Phi P Phi^T, which stays positive definite unless
    Q is below P's rounding level; an update that meets an indefinite S repairs P first.

    ``converged_rtol`` (off by default) switches on the converged-gain path
    (:class:`~observer_gym.estimation.converged_gain.ConvergedGain`): once a predict +
    update cycle with the same ``Phi``, ``Q``, ``C`` and ``R`` objects changes P(k|k) by at
    most ``converged_rtol`` times its largest entry, the next such cycles only propagate x,
    (1) and (5) with that cycle's K_f, gated with its S, and keep its covariances.
    ``steady_cycles`` counts the cycles taken on this path.
    """

    def __init__(
        self,
        x0: np.ndarray,
        P0: np.ndarray,
        gate: Gate | None = None,
        converged_rtol: float | None = None,
    ) -> None:
        x = np.array(x0, dtype=float).reshape(-1)
        P = np.array(P0, dtype=float)
        n = x.shape[0]
        if P.shape != (n, n):
            raise ValueError(f"KalmanFilter: P0 has shape {P.shape}, expected {(n, n)}")
        if not np.allclose(P, P.T, rtol=1e-9, atol=0.0):
            raise ValueError("KalmanFilter: P0 must be symmetric")
        if converged_rtol is not None and not 0.0 < converged_rtol < 1.0:
            raise ValueError(
                f"KalmanFilter: converged_rtol = {converged_rtol!r}, must be None or in (0, 1)"
            )
        self.x = x
        self.P = symmetrised(P)
        self.gate = gate
        self.converged_rtol = converged_rtol
        self._converged = None if converged_rtol is None else ConvergedGain(converged_rtol)
        self.accepted_count = 0
        self.rejected_count = 0
        self.pd_repairs = 0
        self._n = n
        self._eye = np.eye(n)
        self._Phi_P = np.empty((n, n))  # scratch, never handed out
        self._P_unsym = np.empty((n, n))
        self._s_inv_2x2 = np.empty((2, 2))
        self._scratch: dict[int, tuple[np.ndarray, ...]] = {}  # per measurement size m
        # Pending effect of R12 = E[v(k) e(k)^T] on the next predict(): the conditional
        # mean of v(k) given the innovations, the reduction of its covariance, and
        # Cov(x~(k|k), v~(k)). None when no update with R12 is pending.
        self._pending: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    @property
    def dim_x(self) -> int:
        return self._n

    @property
    def steady_cycles(self) -> int:
        """Cycles taken on the converged-gain path (0 without ``converged_rtol``)."""
        return 0 if self._converged is None else self._converged.cycles

    def predict(
        self,
        Phi: np.ndarray,
        Q: np.ndarray,
        Gamma: np.ndarray | None = None,
        u: np.ndarray | None = None,
    ) -> None:
        """Time update (1): x <- Phi x + Gamma u, P <- Phi P Phi^T + Q, symmetrised.

        ``Gamma`` (n, p) and ``u`` (p,) come together or not at all. After an
        :meth:`update` with ``R12``, also adds the part of v(k) that the innovation
        revealed, so that update + predict equals the predictor form (8)-(10).
        """
        if (Gamma is None) != (u is None):
            raise ValueError("KalmanFilter.predict: give both Gamma and u, or neither")
        x = Phi.dot(self.x)
        if Gamma is not None and u is not None:  # both or neither, checked above
            x += Gamma.dot(u)  # (1): Phi x + Gamma u
        converged = self._converged
        if converged is not None:
            P_fixed = converged.predicted_covariance(Phi, Q, self.P, self._pending is None)
            if P_fixed is not None:
                self.x = x
                self.P = P_fixed  # P(k+1|k) at the Riccati fixed point
                return
        P = Phi.dot(self.P, self._Phi_P).dot(Phi.T, self._P_unsym)
        P += Q  # (1): Phi P Phi^T + R1
        if self._pending is not None:
            v_mean, v_cov_reduction, M = self._pending
            x += v_mean  # E[v(k) | innovations]; R12 S^-1 d in (8)
            PhiM = Phi.dot(M)  # Phi Cov(x~(k|k), v~(k)) = -Phi K_f R12^T in (10)
            P += PhiM
            P += PhiM.T
            P -= v_cov_reduction  # R12 S^-1 R12^T in (10)
            self._pending = None
        self.x = x
        P_sym = P + P.T  # symmetrised, inline: this is the hot path
        P_sym *= HALF
        self.P = P_sym

    def update(
        self,
        y: np.ndarray | None,
        C: np.ndarray,
        R: np.ndarray,
        R12: np.ndarray | None = None,
        _retried: bool = False,
    ) -> UpdateResult:
        """Measurement update (5)-(7), Joseph form, for y (m,) = C (m, n) x + e, E[ee^T] = R.

        m may change from call to call. ``y`` None is a missed measurement: x and P stay
        unchanged. ``R12`` (n, m) = E[v(k) e(k)^T], with v(k) the process noise of the
        NEXT :meth:`predict`; x(k|k), P(k|k) do not depend on it, (5)-(7), but the next
        prediction does (8)-(10), so it is carried over to :meth:`predict`.

        Returns an :class:`UpdateResult`. If S turns out not positive definite (P lost
        definiteness to rounding), P is repaired and the update retried once
        (``_retried`` is that internal flag); if S is still indefinite (e.g. R is),
        ``numpy.linalg.LinAlgError`` is raised.
        """
        converged = self._converged
        if y is None:
            if converged is not None:
                converged.no_riccati_step()
            return UpdateResult(False, None, None, float("nan"), None)
        if converged is not None:
            fixed = converged.fixed_point_for(C, R, R12, self.P)
            if fixed is not None:
                return self._fixed_gain_update(y, fixed)
        x, P = self.x, self.P
        n, m = self._n, C.shape[0]
        if R.shape != (m, m):
            raise ValueError(f"KalmanFilter.update: R has shape {R.shape}, expected {(m, m)}")
        CP, B, CtKt, WtB, P_unsym = (
            self._scratch[m] if m in self._scratch else self._make_scratch(m)
        )
        d = y - C.dot(x)  # innovation y - C x(k|k-1), (5) and (27)
        C.dot(P, CP)  # C P = (P C^T)^T, P symmetric
        CPCt = CP.dot(C.T)
        S = CPCt + R  # R2 + C P C^T, (6) and (28)
        if self.gate is not None and not self.gate.accepts(d, S, R, CPCt):
            self.rejected_count += 1
            if converged is not None:
                converged.no_riccati_step()
            return UpdateResult(False, d, S, nis(S, d), None)
        # W = [A^T; K^T] with A = I - K C, so that the Joseph form is one block product.
        W = np.empty((n + m, n))
        Kt = W[n:]
        if m == 2:  # K_f^T = S^-1 C P (6), closed form, inline: this is the hot path
            (a, b), (b2, c) = S.tolist()
            b = 0.5 * (b + b2)
            det = a * c - b * b
            if a > 0.0 and det > 0.0:
                S_inv = self._s_inv_2x2
                S_inv[0, 0] = c / det
                S_inv[1, 1] = a / det
                S_inv[0, 1] = S_inv[1, 0] = -b / det
                S_inv.dot(CP, Kt)
                d0, d1 = d.tolist()
                nis_value = (c * d0 * d0 - 2.0 * b * d0 * d1 + a * d1 * d1) / det
            else:
                nis_value = None
        else:
            nis_value = self._gain_transposed(S, CP, d, Kt)
        if nis_value is None:  # S not positive definite: P lost definiteness to rounding
            if _retried:
                raise np.linalg.LinAlgError("S = C P C^T + R is not positive definite")
            self.P = self._repair(P)
            return self.update(y, C, R, R12, _retried=True)
        K = Kt.T
        if R12 is not None or self._pending is not None:
            self._carry_cross_covariance(C, S, d, K, R12)
        self.x = x + d.dot(Kt)  # (5): x + K_f (y - C x)
        np.subtract(self._eye, C.T.dot(Kt, CtKt), W[:n])  # A^T = I - C^T K^T
        B[:n, :n] = P
        B[n:, n:] = R
        # (7) in Joseph form: (I - K C) P (I - K C)^T + K R2 K^T = W^T diag(P, R2) W.
        W.T.dot(B, WtB).dot(W, P_unsym)
        # Symmetrise and check positive definiteness with one factorisation: dpotrf reads
        # the upper triangle, and P = U^T U is exactly symmetric (BLAS syrk).
        U, info = dpotrf(P_unsym)
        if info == 0 and SYRK_IS_SYMMETRIC:
            self.P = U.T.dot(U)
        else:
            P_sym = symmetrised(P_unsym)
            self.P = P_sym if is_positive_definite(P_sym) else self._repair(P_sym)
        self.accepted_count += 1
        if converged is not None:
            plain = R12 is None and self._pending is None
            converged.full_update_done(C, R, P, self.P, S, CPCt, Kt, plain)
        return UpdateResult(True, d, S, nis_value, K)

    def _fixed_gain_update(self, y: np.ndarray, fixed: FixedPoint) -> UpdateResult:
        """(5) with the fixed point's K_f, gated with its S; a rejected measurement leaves
        the converged-gain path."""
        C, S, Kt = fixed.C, fixed.S, fixed.Kt
        assert self._converged is not None  # a fixed point is the converged path's
        d = y - C.dot(self.x)
        if self.gate is not None and not self.gate.accepts(d, S, fixed.R, fixed.CPCt):
            self.rejected_count += 1
            self._converged.leave()
            return UpdateResult(False, d, S, nis(S, d), None)
        self.x = self.x + d.dot(Kt)  # (5): x + K_f (y - C x)
        self.P = fixed.P_filt
        self.accepted_count += 1
        self._converged.cycles += 1
        return UpdateResult(True, d, S, nis(S, d), Kt.T)

    def _repair(self, P: np.ndarray) -> np.ndarray:
        """P made positive definite by :func:`~observer_gym.estimation.covariance.repaired`,
        counted in ``pd_repairs``."""
        self.pd_repairs += 1
        return repaired(P)

    def _make_scratch(self, m: int) -> tuple[np.ndarray, ...]:
        n = self._n
        scratch = (
            np.empty((m, n)),  # C P
            np.zeros((n + m, n + m)),  # diag(P, R); the off-diagonal blocks stay zero
            np.empty((n, n)),  # C^T K^T
            np.empty((n, n + m)),  # W^T diag(P, R)
            np.empty((n, n)),  # Joseph product before symmetrisation
        )
        self._scratch[m] = scratch
        return scratch

    def _gain_transposed(
        self, S: np.ndarray, CP: np.ndarray, d: np.ndarray, out: np.ndarray
    ) -> float | None:
        """Write K_f^T = S^-1 C P (6) into ``out`` (m, n); return the NIS d^T S^-1 d.

        None if S is not positive definite. (m = 2 is inlined in :meth:`update`.)
        """
        if S.shape[0] == 1:
            s = float(S[0, 0])
            if s > 0.0:
                np.divide(CP, s, out=out)
                return float(d[0]) ** 2 / s
        try:
            factor = scipy.linalg.cho_factor(S)
        except np.linalg.LinAlgError:
            return None
        out[...] = scipy.linalg.cho_solve(factor, CP)
        return float(d @ scipy.linalg.cho_solve(factor, d))

    def _carry_cross_covariance(
        self, C: np.ndarray, S: np.ndarray, d: np.ndarray, K: np.ndarray, R12: np.ndarray | None
    ) -> None:
        """Condition the next step's process noise v(k) on this innovation d.

        With M = Cov(x~, v~) (zero before the first update of a step), the innovation's
        covariance with v~ is N = M^T C^T + R12, so E[v | d] += N S^-1 d, Cov(v~) -= N S^-1 N^T
        and M <- M - K_f N^T. For M = 0 these give the R12 terms of (8)-(10).
        """
        n, m = self.dim_x, d.shape[0]
        if self._pending is None:
            v_mean, v_red, M = np.zeros(n), np.zeros((n, n)), np.zeros((n, n))
        else:
            v_mean, v_red, M = self._pending
        N = np.dot(M.T, C.T)
        if R12 is not None:
            N = N + np.asarray(R12, dtype=float).reshape(n, m)
        L = right_divide(N, S)
        self._pending = (v_mean + np.dot(L, d), v_red + np.dot(L, N.T), M - np.dot(K, N.T))


def predictor_step(
    x_pred: np.ndarray,
    P_pred: np.ndarray,
    y: np.ndarray | None,
    C: np.ndarray,
    Phi: np.ndarray,
    Q: np.ndarray,
    R: np.ndarray,
    R12: np.ndarray | None = None,
    Gamma: np.ndarray | None = None,
    u: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """One step of the one-step predictor (8)-(10): (x(k|k-1), P(k|k-1)) -> (k+1|k).

    x(k+1|k) = Phi x(k|k-1) + Gamma u(k) + K(k) (y(k) - C x(k|k-1))             (8)
    K(k)     = (Phi P C^T + R12) (R2 + C P C^T)^-1                              (9)
    P(k+1|k) = Phi P Phi^T + R1 - K(k) (Phi P C^T + R12)^T                      (10)

    (R1 = ``Q``, R2 = ``R``.) (10) is evaluated in the algebraically equal Joseph-like form
    (Phi - K C) P (Phi - K C)^T + [I, -K] [[R1, R12], [R12^T, R2]] [I, -K]^T, a sum of PSD
    terms, then symmetrised. With ``y`` None it is pure prediction (the measurement terms
    of (8) and (10) vanish).
    """
    x_pred = np.asarray(x_pred, dtype=float)
    P_pred = np.asarray(P_pred, dtype=float)
    if (Gamma is None) != (u is None):
        raise ValueError("predictor_step: give both Gamma and u, or neither")
    x_next = np.dot(Phi, x_pred)
    if Gamma is not None and u is not None:  # both or neither, checked above
        x_next = x_next + np.dot(Gamma, u)
    if y is None:
        P_next = symmetrised(np.dot(np.dot(Phi, P_pred), Phi.T) + Q)
        return x_next, P_next if is_positive_definite(P_next) else repaired(P_next)
    n, m = x_pred.shape[0], C.shape[0]
    R12 = np.zeros((n, m)) if R12 is None else np.asarray(R12, dtype=float).reshape(n, m)
    N = np.dot(np.dot(Phi, P_pred), C.T) + R12  # Phi P C^T + R12
    S = np.dot(np.dot(C, P_pred), C.T) + R  # R2 + C P C^T
    K = right_divide(N, S)  # (9)
    x_next = x_next + np.dot(K, np.asarray(y, dtype=float) - np.dot(C, x_pred))  # (8)
    A = Phi - np.dot(K, C)
    KR12t = np.dot(K, R12.T)
    P_next = np.dot(np.dot(A, P_pred), A.T) + Q + np.dot(np.dot(K, R), K.T) - KR12t - KR12t.T
    P_next = symmetrised(P_next)  # (10)
    return x_next, P_next if is_positive_definite(P_next) else repaired(P_next)
