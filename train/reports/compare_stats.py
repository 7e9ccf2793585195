"""The statistics of ``observer-gym compare``: per pair and metric a mean with its Student
t interval (rates: a Wilson interval), and the paired observer − oracle difference of the
primary metric, episode by episode on the same seeds.

:func:`analyse_pairs` turns the episodes' records of every pair into the pairs of
``results.json`` (metrics per episode, the task's summary, statistics, ``vs_oracle``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np
from scipy import stats

from observer_gym.train.reports.consistency import episode_consistency, nees_flag

CONFIDENCE = 0.95  # of every interval
PERCENT = f"{CONFIDENCE * 100:g} %"  # as the tables write it
ORACLE = "oracle"
BETTER = ("lower", "higher")

# A metric of the table: key -> (label, unit, scale from the stored value to the unit,
# digits, "lower" or "higher" is better)
MetricSpec = tuple[str, str, float, int, str]
# A counted column of the table: episode key -> (label, its values in the order shown)
CountSpec = tuple[str, tuple[str, ...]]


def _interval_of_nothing(n: int, method: str) -> dict[str, Any]:
    """An interval's fields with every value None, for :func:`mean_interval` and
    :func:`rate_interval` to fill."""
    return {"n": n, "mean": None, "half_width": None, "low": None, "high": None, "method": method}


def mean_interval(values: Sequence[float | None], confidence: float = CONFIDENCE) -> dict[str, Any]:
    """Mean of the values that are not None with its Student t interval.

    Returns ``n`` (values used), ``mean``, ``half_width`` = t_{(1+c)/2, n-1} s / sqrt(n)
    (s: sample standard deviation), ``low``, ``high`` and ``method`` ("student-t"), in the
    values' unit. With n = 1 the interval is undefined (None); with n = 0 so is the mean.
    """
    x = np.array([float(v) for v in values if v is not None], dtype=float)
    n = len(x)
    result = _interval_of_nothing(n, "student-t")
    if n == 0:
        return result
    mean = float(np.mean(x))
    result["mean"] = mean
    if n >= 2:
        sem = float(np.std(x, ddof=1)) / math.sqrt(n)
        half_width = float(stats.t.ppf(0.5 + confidence / 2.0, n - 1)) * sem
        result.update(half_width=half_width, low=mean - half_width, high=mean + half_width)
    return result


def rate_interval(values: Sequence[bool | None], confidence: float = CONFIDENCE) -> dict[str, Any]:
    """Fraction of True among the values that are not None with its Wilson score interval
    (SciPy's ``binomtest(...).proportion_ci(method="wilson")``, as the BallCatcher summary).

    Returns ``n``, ``mean`` (the rate, 0-1), ``half_width`` (None: the interval is not
    symmetric), ``low``, ``high`` and ``method`` ("wilson"); all None but n for n = 0.
    """
    x = [bool(v) for v in values if v is not None]
    n = len(x)
    result = _interval_of_nothing(n, "wilson")
    if n == 0:
        return result
    successes = sum(x)
    interval = stats.binomtest(successes, n).proportion_ci(
        confidence_level=confidence, method="wilson"
    )
    result.update(mean=successes / n, low=float(interval.low), high=float(interval.high))
    return result


def is_flag(values: Sequence[Any]) -> bool:
    """True if every value that is not None is a boolean (an outcome such as "caught")."""
    present = [v for v in values if v is not None]
    return bool(present) and all(isinstance(v, bool | np.bool_) for v in present)


def metric_statistics(values: Sequence[Any], confidence: float = CONFIDENCE) -> dict[str, Any]:
    """:func:`rate_interval` for booleans, else :func:`mean_interval` (None values skipped)."""
    if is_flag(values):
        return rate_interval(values, confidence)
    return mean_interval(values, confidence)


def paired_difference(
    observer_values: Sequence[Any],
    oracle_values: Sequence[Any],
    confidence: float = CONFIDENCE,
) -> dict[str, Any]:
    """Observer minus oracle, episode by episode (same seeds), over the episodes where both
    have a value: :func:`mean_interval` of the differences (booleans count 0/1, so a rate's
    difference is a fraction: x 100 for percentage points), plus ``observer_mean``,
    ``oracle_mean`` (over those episodes) and ``ratio`` = observer_mean / oracle_mean
    (None when the oracle's mean is 0)."""
    if len(observer_values) != len(oracle_values):
        raise ValueError(
            f"paired values differ in length: {len(observer_values)} and {len(oracle_values)}"
        )
    pairs = [
        (float(o), float(r))
        for o, r in zip(observer_values, oracle_values, strict=True)
        if o is not None and r is not None
    ]
    result = mean_interval([o - r for o, r in pairs], confidence)
    result["method"] = "paired student-t"
    observer_mean = float(np.mean([o for o, _ in pairs])) if pairs else None
    oracle_mean = float(np.mean([r for _, r in pairs])) if pairs else None
    result["observer_mean"] = observer_mean
    result["oracle_mean"] = oracle_mean
    ratio = None
    if observer_mean is not None and oracle_mean:  # undefined for an oracle mean of 0
        ratio = observer_mean / oracle_mean
    result["ratio"] = ratio
    return result


def compare_metrics(task: Any) -> dict[str, MetricSpec]:
    """The task's ``COMPARE_METRICS`` (key -> label, unit, scale from the stored value to
    the unit, digits, "lower" or "higher" is better), checked; the first is primary."""
    metrics = dict(getattr(task, "COMPARE_METRICS", {}))
    if not metrics:
        raise ValueError(f"task {task.__name__} defines no COMPARE_METRICS")
    for key, spec in metrics.items():
        if len(spec) != 5 or spec[4] not in BETTER:
            raise ValueError(
                f"{task.__name__}.COMPARE_METRICS[{key!r}] must be (label, unit, scale, "
                f"digits, 'lower' or 'higher'), got {spec!r}"
            )
    return metrics


def compare_counts(task: Any) -> dict[str, CountSpec]:
    """The task's optional ``COMPARE_COUNTS`` (episode key -> label, its values in the
    order shown: a column counting the pair's episodes of each value), checked; {} if it
    has none."""
    counts = dict(getattr(task, "COMPARE_COUNTS", {}))
    for key, spec in counts.items():
        if len(spec) != 2 or not isinstance(spec[0], str) or isinstance(spec[1], str):
            raise ValueError(
                f"{task.__name__}.COMPARE_COUNTS[{key!r}] must be (label, values), got {spec!r}"
            )
    return counts


def value_counts(values: Sequence[Any], order: Sequence[str]) -> dict[str, int]:
    """How many of ``values`` are each of ``order`` (0 for one that none is), then any other
    value in the order met; None values are not counted."""
    counts = dict.fromkeys(order, 0)
    for value in values:
        if value is not None:
            counts[str(value)] = counts.get(str(value), 0) + 1
    return counts


def episode_values(task: Any, record: Mapping[str, Any]) -> dict[str, Any]:
    """One episode's metrics from its record: the task's ``episode_metrics``, the
    observer's consistency (:func:`~observer_gym.train.reports.consistency.episode_consistency`:
    NEES and NIS) and, if the task has one, its ``compare_extras`` (numbers derived for
    the tables)."""
    values = {**task.episode_metrics(record), **episode_consistency(record)}
    extras = getattr(task, "compare_extras", None)
    if extras is not None:
        values.update(extras(values))
    return values


def metrics_statistics(
    episodes: Sequence[Mapping[str, Any]], metrics: Mapping[str, MetricSpec]
) -> dict[str, dict[str, Any]]:
    """:func:`metric_statistics` of every metric of ``metrics`` over ``episodes`` (dicts
    of :func:`episode_values`; a missing value counts as None)."""
    return {key: metric_statistics([e.get(key) for e in episodes]) for key in metrics}


class Analysis(NamedTuple):
    """What :func:`analyse_pairs` finds."""

    pairs: list[dict[str, Any]]  # one per (observer, controller), as results.json holds it
    starts_match: bool  # episode i of every pair starts from the same state


def analyse_pairs(
    task: Any,
    pairs: Sequence[tuple[str, str]],
    folders: Sequence[str],
    seeds: Sequence[int],
    records: Sequence[Mapping[str, Any]],
    observed: Mapping[str, Mapping[str, Any]],
) -> Analysis:
    """Per pair (``records`` holds the episodes of ``pairs[0]`` on ``seeds``, then those of
    ``pairs[1]``, ...): each episode's metrics (the task's ``episode_metrics`` and, if it
    has one, ``compare_extras``; and the filter's consistency,
    :func:`~observer_gym.train.reports.consistency.episode_consistency`), the task's summary,
    the statistics of every metric of :func:`compare_metrics` and, with "oracle" among
    the observers, the paired difference of the primary metric from the oracle with the
    same controller; each pair also carries ``observed[observer]``
    (:meth:`observer_gym.train.experiments.request.ObserverEntry.record`: obs_mode, pipeline
    options,
    an outside observer's entry); with the task's ``COMPARE_COUNTS``, also ``counts``: per
    counted key, the episodes of each value (:func:`value_counts`)."""
    metrics = compare_metrics(task)
    counted = compare_counts(task)
    primary = next(iter(metrics))
    n = len(seeds)
    by_pair = {pair: records[k * n : (k + 1) * n] for k, pair in enumerate(pairs)}
    results_pairs = []
    for (observer, controller), folder in zip(pairs, folders, strict=True):
        pair_records = by_pair[observer, controller]
        episodes = [
            {"episode": i, "seed": seed, **episode_values(task, record)}
            for i, (seed, record) in enumerate(zip(seeds, pair_records, strict=True))
        ]
        results_pairs.append(
            {
                "observer": observer,
                "controller": controller,
                "folder": folder,
                **observed[observer],
                "controller_config": by_pair[observer, controller][0]["controller"],
                "episodes": episodes,
                "summary": task.summarize(episodes),
                "statistics": metrics_statistics(episodes, metrics),
                # only for a task with counted columns: other folders keep their bytes
                **(
                    {
                        "counts": {
                            key: value_counts([e.get(key) for e in episodes], order)
                            for key, (_, order) in counted.items()
                        }
                    }
                    if counted
                    else {}
                ),
                "consistency": nees_flag(episodes)._asdict(),
                "vs_oracle": None,
            }
        )
    lookup = {(p["observer"], p["controller"]): p for p in results_pairs}
    if any(observer == ORACLE for observer, _ in pairs):
        for pair in results_pairs:
            if pair["observer"] != ORACLE:
                reference = lookup[ORACLE, pair["controller"]]
                pair["vs_oracle"] = paired_difference(
                    [e.get(primary) for e in pair["episodes"]],
                    [e.get(primary) for e in reference["episodes"]],
                )
    starts_match = all(
        np.array_equal(record["state"][0], records[i % n]["state"][0])
        for i, record in enumerate(records)
    )
    return Analysis(results_pairs, starts_match)
