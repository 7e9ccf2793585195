"""Outlier gates: whether a measurement is used, decided from its innovation before the
Kalman update.

:class:`PSigmaGate` is docs/spec/catcher.md's test (27)-(30) (Linderoth et al., ICRA
2010; equation numbers in brackets are that paper's), :class:`ChiSquareGate` bounds the
normalised innovation squared (NIS) d^T S^-1 d, which :func:`nis` computes and
:class:`~observer_gym.estimation.filters.UpdateResult` reports.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

__all__ = ["ChiSquareGate", "Gate", "PSigmaGate", "nis"]


class Gate(Protocol):
    """Decides, before a measurement is used, whether it is an outlier."""

    def accepts(
        self, innovation: np.ndarray, S: np.ndarray, R: np.ndarray, CPCt: np.ndarray
    ) -> bool:
        """``innovation`` d = y - C x (m,), ``S`` = R + C P C^T, ``R`` = R2, ``CPCt``."""
        ...


class PSigmaGate:
    """The paper's outlier test, docs/spec/catcher.md (27)-(30).

    With d = y - C x (27) and R = R2 + C P C^T (28), sigma^2 = d^T R d / d^T d is the
    variance along d (29); the measurement is an outlier if ||d|| > p sigma (30).
    """

    def __init__(self, p: float) -> None:
        if not p > 0.0:
            raise ValueError(f"PSigmaGate: p = {p!r}, must be > 0")
        self.p = float(p)

    def accepts(
        self, innovation: np.ndarray, S: np.ndarray, R: np.ndarray, CPCt: np.ndarray
    ) -> bool:
        d = np.asarray(innovation, dtype=float)
        dd = float(d @ d)
        if dd == 0.0:
            return True
        sigma2 = float(d @ S @ d) / dd  # (29), S = R2 + R_yhat (28)
        return dd <= self.p * self.p * sigma2  # not an outlier: ||d|| <= p sigma (30)


class ChiSquareGate:
    """Accept when the NIS d^T S^-1 d is below the chi-square(m) ``probability`` quantile."""

    def __init__(self, probability: float = 0.997) -> None:
        if not 0.0 < probability < 1.0:
            raise ValueError(f"ChiSquareGate: probability = {probability!r}, must be in (0, 1)")
        self.probability = float(probability)
        self._threshold: dict[int, float] = {}

    def threshold(self, m: int) -> float:
        """The NIS bound for an m-dimensional measurement (cached per m)."""
        if m not in self._threshold:
            import scipy.stats  # imported on use: scipy.stats takes ~0.6 s to import

            self._threshold[m] = float(scipy.stats.chi2.ppf(self.probability, m))
        return self._threshold[m]

    def accepts(
        self, innovation: np.ndarray, S: np.ndarray, R: np.ndarray, CPCt: np.ndarray
    ) -> bool:
        d = np.asarray(innovation, dtype=float)
        return nis(S, d) <= self.threshold(d.shape[0])


def nis(S: np.ndarray, d: np.ndarray) -> float:
    """d^T S^-1 d: in closed form for one image point (m <= 2), else by a solve. (SciPy's
    Cholesky wrappers cost ~40 us per call at this size: most of a gated update.)"""
    m = d.shape[0]
    if m == 1:
        return float(d[0] * d[0] / S[0, 0])
    if m == 2:
        (a, b), (b2, c) = S.tolist()
        d0, d1 = d.tolist()
        b = 0.5 * (b + b2)
        return (c * d0 * d0 - 2.0 * b * d0 * d1 + a * d1 * d1) / (a * c - b * b)
    return float(d @ np.linalg.solve(S, d))
