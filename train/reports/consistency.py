"""Filter consistency per episode: NEES against the simulator's truth, and NIS.

    NEES(k) = e(k)^T P(k)^-1 e(k),   e(k) = x_hat(k) - x(k)                  (over n_k dof)
    NIS(k)  = sum over the step's updates of d^T S^-1 d                    (over m_k dof)

A consistent filter has E[NEES] = n_k and E[NIS] = m_k (Bar-Shalom, Li & Kirubarajan,
"Estimation with Applications to Tracking and Navigation", 2001, sec. 5.4).

The band (:func:`chi_square_band`, :func:`nees_flag`): over a cell's episodes, the sum of
the episodes' mean NEES against a chi-square with the sum of their mean dof, as
Bar-Shalom's Monte Carlo NEES test takes N runs: one sample per episode. An episode's mean
NEES is an average over correlated steps, so its spread is narrower than chi-square(n)/n
and this band is the wider, conservative one: a filter outside it claims much less (or
much more) error than it has. NEES is taken
over the state entries the observer is uncertain about: those with a finite, positive
variance (entries it knows exactly, e.g. the robot's own joints, have zero variance and
no error to normalise), in the directions the covariance does not claim to know exactly
(:func:`nees_per_step`); a step whose covariance is not finite has no NEES. NIS comes
from the observer (``Estimate.nis``, ``nis_dof``); observers without an innovation
covariance report none.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np
from scipy import stats

__all__ = [
    "NEES_COLUMN",
    "CellConsistency",
    "chi_square_band",
    "consistency_text",
    "episode_consistency",
    "nees_flag",
    "nees_per_step",
]

# Correlation eigenvalues below this are directions the covariance holds exactly known.
RANK_TOL = 1e-9


def nees_per_step(
    estimates: np.ndarray, covariances: Sequence[np.ndarray], truth: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """NEES and its degrees of freedom at each step (NaN and 0 where it has none).

    Over the entries with a finite, positive variance, in the eigenbasis of their
    correlation matrix: directions whose correlation eigenvalue is below
    :data:`RANK_TOL` are ones the observer claims to know exactly and are left out, so the
    dof is the covariance's numerical rank. numpy.linalg.eigh, not a Cholesky solve, for
    that. An error in such a direction, or in an entry of zero variance, is not counted: a
    claim of exact knowledge is not checked here."""
    nees = np.full(len(estimates), np.nan)
    dof = np.zeros(len(estimates), dtype=int)
    for k, (mean, P, x) in enumerate(zip(estimates, covariances, truth, strict=True)):
        P = np.asarray(P, dtype=float)
        variances = np.diag(P)
        uncertain = np.isfinite(variances) & (variances > 0.0)
        if not uncertain.any():
            continue
        error = np.asarray(mean, dtype=float)[uncertain] - np.asarray(x, dtype=float)[uncertain]
        block = P[np.ix_(uncertain, uncertain)]
        if not (np.all(np.isfinite(block)) and np.all(np.isfinite(error))):
            continue
        # Correlation matrix D^-1/2 P D^-1/2 and the error in the same scaling.
        scale = 1.0 / np.sqrt(np.diag(block))
        eigenvalues, eigenvectors = np.linalg.eigh(block * np.outer(scale, scale))
        kept = eigenvalues > RANK_TOL
        # NEES = sum over kept directions of (v_i^T D^-1/2 e)^2 / lambda_i
        projected = eigenvectors[:, kept].T.dot(error * scale)
        nees[k] = float(np.sum(projected**2 / eigenvalues[kept]))
        dof[k] = int(kept.sum())
    return nees, dof


def episode_consistency(record: Mapping[str, Any]) -> dict[str, float | None]:
    """The episode's mean NEES and mean NIS with their mean degrees of freedom, from a
    :func:`observer_gym.train.experiments.episode.run_episode` record; {} for the oracle (no
    estimate).
    ``nees_ratio`` = mean NEES / mean dof (1 for a consistent filter); None where the
    observer gave none."""
    if record.get("nees") is None:
        return {}
    out: dict[str, float | None] = {}
    for name in ("nees", "nis"):
        values, dof = np.asarray(record[name], float), np.asarray(record[f"{name}_dof"], float)
        has = np.isfinite(values) & (dof > 0)
        if not has.any():
            out.update({f"{name}_mean": None, f"{name}_dof": None, f"{name}_ratio": None})
            continue
        mean, mean_dof = float(values[has].mean()), float(dof[has].mean())
        ratio = mean / mean_dof
        out.update({f"{name}_mean": mean, f"{name}_dof": mean_dof, f"{name}_ratio": ratio})
    return out


def chi_square_band(dof: float, confidence: float = 0.95) -> tuple[float, float]:
    """The two-sided ``confidence`` band of chi-square(``dof``) / ``dof``: where a
    consistent filter's NEES (or NIS) per degree of freedom lies."""
    tail = 0.5 * (1.0 - confidence)
    return (
        float(stats.chi2.ppf(tail, dof) / dof),
        float(stats.chi2.ppf(1.0 - tail, dof) / dof),
    )


class CellConsistency(NamedTuple):
    """A cell's NEES over its episodes: the summed episode means over the summed dof,
    the 95 % chi-square band of that dof (None, None without NEES), and whether the ratio
    lies inside it."""

    nees_ratio: float | None
    band: tuple[float, float] | None
    consistent: bool | None


def nees_flag(episodes: Sequence[Mapping[str, Any]]) -> CellConsistency:
    """The :class:`CellConsistency` of a cell from its episodes'
    :func:`episode_consistency` entries (``nees_mean``, ``nees_dof``)."""
    pairs = [
        (e["nees_mean"], e["nees_dof"])
        for e in episodes
        if e.get("nees_mean") is not None and e.get("nees_dof")
    ]
    if not pairs:
        return CellConsistency(None, None, None)
    nees, dof = (float(sum(column)) for column in zip(*pairs, strict=True))
    band = chi_square_band(dof)
    ratio = nees / dof
    return CellConsistency(ratio, band, band[0] <= ratio <= band[1])


NEES_COLUMN = "NEES/dof [95 % band]"


def consistency_text(cell: Mapping[str, Any] | None) -> str:
    """A table cell for a cell's :class:`CellConsistency` (as a dict): "0.93 [0.61, 1.48]",
    "91.30 ⚠ [0.61, 1.48]" when the ratio leaves the band, "n/a" without NEES."""
    if not cell or cell.get("nees_ratio") is None:
        return "n/a"
    low, high = cell["band"]
    mark = "" if cell["consistent"] else " ⚠"
    return f"{cell['nees_ratio']:.2f}{mark} [{low:.2f}, {high:.2f}]"


NEES_KEY_TEXT = (
    f"{NEES_COLUMN}: the episodes' summed mean NEES over their summed degrees of freedom "
    "(1 for a filter whose covariance tells the truth), taken over the steps where the "
    "observer's model holds (BallCatcher-v1: the ball's free flight, up to its first touch "
    "of the box), and the band a chi-square with that "
    "many dof gives with 95 % probability; ⚠ marks a ratio outside it: the observer claims "
    "much less (above) or much more (below) error than it has (docs/observers.md)."
)
