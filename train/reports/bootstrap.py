"""The interquartile mean and the stratified-bootstrap percentile interval of rliable
(Agarwal et al., 2021), in NumPy and SciPy, drawing the same random numbers as rliable
1.x: the same scores and seed give rliable's intervals to the last bit.

- :func:`iqm` is ``rliable.metrics.aggregate_iqm``: SciPy's 25 % trimmed mean of all the
  scores (``scipy.stats.trim_mean(scores, 0.25, axis=None)``).
- :func:`mean_of_task_means` is ``rliable.metrics.aggregate_mean``: the mean over tasks of
  each task's mean over runs.
- :func:`interval_estimates` is ``rliable.library.get_interval_estimates(..., method=
  "percentile")`` on one score array, with NumPy's global random state seeded with
  ``seed`` before the call. rliable's ``StratifiedBootstrap`` (an ``arch`` ``IIDBootstrap``)
  draws each replication's indices with ``np.random.choice(runs, scores.shape)``, from
  NumPy's global random state (the ``random_state`` it takes does not reach that draw):
  every entry of the array picks a run of its own column (task, and evaluation point),
  so the runs are resampled within each stratum. Each replication applies ``function``;
  the interval is ``np.percentile`` of the replications at 100·α and 100·(1 - α),
  α = (1 - confidence) / 2, as ``arch``'s ``conf_int`` computes them. Here the draws come
  from a ``RandomState(seed)`` of their own, whose stream is the global state's after
  ``np.random.seed(seed)``: the caller's random state is not touched.

``tests/train/reports/test_bootstrap.py`` holds these to rliable's own numbers where rliable is
installed.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import scipy.stats

CONFIDENCE = 0.95
BOOTSTRAP_SEED = 0


def iqm(scores: Any) -> float:
    """The interquartile mean (25 % trimmed mean) of all of ``scores``, flattened."""
    return float(scipy.stats.trim_mean(np.asarray(scores, dtype=float), 0.25, axis=None))


def mean_of_task_means(scores: Any) -> Any:
    """The mean over tasks (axis 1 on) of each task's mean over runs (axis 0)."""
    return np.mean(np.mean(scores, axis=0), axis=0)


def _checked(scores: Any, reps: int, confidence: float, seed: int) -> np.ndarray:
    array = np.asarray(scores, dtype=float)
    if array.ndim < 2 or 0 in array.shape:
        raise ValueError(
            f"scores must be an array of runs x tasks [x ...] with at least one run and one "
            f"task, got shape {array.shape}"
        )
    if isinstance(reps, bool) or not isinstance(reps, int | np.integer) or reps < 1:
        raise ValueError(f"reps must be an integer >= 1, got {reps!r}")
    if isinstance(confidence, bool) or not (0.0 < float(confidence) < 1.0):
        raise ValueError(f"confidence must be strictly between 0 and 1, got {confidence!r}")
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    return array


def interval_estimates(
    scores: Any,
    function: Callable[[np.ndarray], Any],
    reps: int,
    confidence: float = CONFIDENCE,
    seed: int = BOOTSTRAP_SEED,
) -> tuple[Any, np.ndarray]:
    """``function(scores)`` and its stratified-bootstrap percentile interval, an array
    (2, k) of lower and upper bounds for the k values ``function`` returns (one for a
    scalar). ``scores``: runs x tasks [x points]; see the module docstring.

    Raises:
        ValueError: ``scores`` is not an array of at least one run and one task, or
            ``reps``, ``confidence`` or ``seed`` is out of range.
    """
    array = _checked(scores, reps, confidence, seed)
    point = function(array)
    runs = array.shape[0]
    # the strata: each entry keeps its task (and point) and draws a run of its own
    strata = np.ogrid[tuple(slice(n) for n in (0, *array.shape[1:]))][1:]
    # rliable draws from NumPy's global state; the same stream, in a state of our own
    random = np.random.RandomState(seed)  # rliable's legacy stream
    results = np.zeros((reps, np.size(point)))
    for k in range(reps):
        indices = random.choice(runs, array.shape, replace=True)
        resampled = array[tuple([indices, *strata])]
        results[k] = function(resampled)
    alpha = (1.0 - confidence) / 2
    percentiles = 100 * np.array([alpha, 1.0 - alpha])
    lower = np.zeros(results.shape[1])
    upper = np.zeros(results.shape[1])
    for i in range(results.shape[1]):
        lower[i], upper[i] = np.percentile(results[:, i], list(percentiles))
    return point, np.vstack((lower, upper))
