"""Normalised scores of a benchmark run, per level and over levels.

Per episode, the level's headline metric m becomes the score (m - floor) / (oracle -
floor), with the level's reference values from the suite file
(:class:`~observer_gym.train.experiments.benchmark.suite.References`): the oracle
observer with the reference controller scores 1 on average by definition, the floor (the
worse of the raw camera baseline and doing nothing) 0. A lower-is-better metric needs no
sign flip: both differences change sign together.

A level's score is the mean of its episodes' scores, with a 95 % percentile interval of
rliable's bootstrap over the episodes. The aggregate over levels is rliable's
interquartile mean (``rliable.metrics.aggregate_iqm``) of the level scores, with a
stratified-bootstrap 95 % interval: the episodes are resampled within each level (the
strata), the level means recomputed, their IQM taken. With three levels the 25 % trim
removes none, so the IQM equals the mean of the level scores (docs/benchmark.md).
Both are computed in NumPy and SciPy (:mod:`observer_gym.train.reports.bootstrap`, which
draws rliable's random numbers: rliable's results to the last bit, without rliable).
The bootstrap is seeded (:func:`observer_gym.train.reports.aggregate._interval_estimates`):
the same episodes give the same intervals, which is what ``benchmark --check`` re-derives.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import NamedTuple

import numpy as np

from observer_gym.train.experiments.benchmark.suite import References
from observer_gym.train.reports.aggregate import _interval_estimates
from observer_gym.train.reports.bootstrap import iqm

BOOTSTRAP_REPS = 2_000
METHOD = (
    "per level: mean of the episodes' normalised scores, percentile bootstrap over the "
    "episodes; over levels: IQM of the level scores (rliable), stratified bootstrap over "
    f"the episodes within each level; 95 %, {BOOTSTRAP_REPS} replications, seed 0"
)


class Interval(NamedTuple):
    """A point estimate with its 95 % interval."""

    value: float
    low: float
    high: float


class LevelScore(NamedTuple):
    """One level's raw metric and normalised score."""

    level: str
    episodes: int
    metric_mean: float  # the headline metric's mean over the episodes, its own unit
    floor: str  # which baseline is the floor: "raw" or "idle"
    floor_value: float
    oracle_value: float
    score: Interval


class Scores(NamedTuple):
    """Every level's score and the aggregate over levels."""

    levels: tuple[LevelScore, ...]
    aggregate: Interval


def normalised(values: Sequence[float], refs: References, better: str) -> np.ndarray:
    """Each value's normalised score against ``refs`` (see the module docstring)."""
    _, floor = refs.floor(better)
    return (np.asarray(values, dtype=float) - floor) / (refs.oracle - floor)


def _iqm_of_level_means(matrix: np.ndarray) -> float:
    """rliable's IQM of the column (level) means of ``matrix`` (episodes x levels)."""
    return iqm(np.mean(matrix, axis=0, keepdims=True))


def _mean(matrix: np.ndarray) -> float:
    return float(np.mean(matrix))


def _interval(matrix: np.ndarray, function: Callable[[np.ndarray], float], reps: int) -> Interval:
    """``function(matrix)`` with its (rliable's) bootstrap 95 % interval, seeded."""
    point, interval = _interval_estimates(matrix, function, reps)
    low, high = np.ravel(interval)
    return Interval(float(point), float(low), float(high))


def score_levels(
    values: Mapping[str, Sequence[float]],
    references: Mapping[str, References],
    better: str,
    reps: int = BOOTSTRAP_REPS,
) -> Scores:
    """The :class:`Scores` of ``values`` (per level, in the suite's order: the headline
    metric of each episode). Every level must have the same number of episodes (the
    stratified bootstrap's matrix).

    Raises:
        ValueError: no level, an empty level, or levels of different lengths.
    """
    if not values:
        raise ValueError("scores need at least one level")
    counts = {name: len(v) for name, v in values.items()}
    if min(counts.values()) < 1 or len(set(counts.values())) != 1:
        raise ValueError(f"every level needs the same number (>= 1) of episodes, got {counts}")
    columns, levels = [], []
    for name, level_values in values.items():
        refs = references[name]
        column = normalised(level_values, refs, better)
        interval = _interval(column[:, None], _mean, reps)
        floor_name, floor_value = refs.floor(better)
        levels.append(
            LevelScore(
                name,
                len(column),
                float(np.mean(level_values)),
                floor_name,
                floor_value,
                refs.oracle,
                interval,
            )
        )
        columns.append(column)
    matrix = np.stack(columns, axis=1)
    return Scores(tuple(levels), _interval(matrix, _iqm_of_level_means, reps))
