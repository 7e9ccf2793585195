"""reports/bootstrap.py: rliable's IQM and stratified-bootstrap percentile interval in
NumPy and SciPy, equal to rliable's own numbers to the last bit (where rliable is
installed), on random score arrays and seeds; bad input is a ValueError; the benchmark's
scores and the scores across seeds need no rliable."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from observer_gym.train.reports.bootstrap import interval_estimates, iqm, mean_of_task_means


def _rliable_interval(scores, function, reps, seed, confidence=0.95):
    """rliable's get_interval_estimates with NumPy's global state seeded (restored)."""
    library = pytest.importorskip("rliable.library")
    saved = np.random.get_state()  # noqa: NPY002  (the global state rliable draws from)
    np.random.seed(seed)  # noqa: NPY002
    try:
        points, intervals = library.get_interval_estimates(
            {"s": scores}, function, reps=reps, confidence_interval_size=confidence
        )
    finally:
        np.random.set_state(saved)  # noqa: NPY002
    return points["s"], intervals["s"]


@pytest.mark.parametrize(
    ("shape", "seed", "reps"),
    [((10, 3), 0, 300), ((7, 1), 3, 200), ((46, 3), 0, 500), ((2, 5), 12345, 100), ((1, 2), 7, 50)],
)
def test_iqm_of_level_means_and_its_interval_are_rliables(shape, seed, reps):
    metrics = pytest.importorskip("rliable.metrics")
    scores = np.random.default_rng(seed + 1).normal(size=shape)

    def theirs(x):
        return metrics.aggregate_iqm(np.mean(x, axis=0, keepdims=True))

    def ours(x):
        return iqm(np.mean(x, axis=0, keepdims=True))

    point, interval = _rliable_interval(scores, theirs, reps, seed)
    our_point, our_interval = interval_estimates(scores, ours, reps, seed=seed)
    assert our_point == point
    np.testing.assert_array_equal(our_interval, interval)
    assert iqm(scores) == metrics.aggregate_iqm(scores)


@pytest.mark.parametrize(("runs", "seed", "confidence"), [(8, 0, 0.95), (3, 4, 0.9), (25, 1, 0.5)])
def test_iqm_across_seeds_is_rliables(runs, seed, confidence):
    metrics = pytest.importorskip("rliable.metrics")
    scores = np.random.default_rng(seed).exponential(size=(runs, 1))
    point, interval = _rliable_interval(
        scores, lambda x: np.array([metrics.aggregate_iqm(x)]), 400, seed, confidence
    )
    ours = interval_estimates(scores, lambda x: np.array([iqm(x)]), 400, confidence, seed)
    np.testing.assert_array_equal(ours[0], point)
    np.testing.assert_array_equal(ours[1], interval)


def test_a_band_over_evaluation_points_is_rliables():
    """The learning curves' band: runs x 1 task x points, every entry resampled within its
    point (aggregate.curve_band)."""
    metrics = pytest.importorskip("rliable.metrics")
    scores = np.random.default_rng(9).normal(size=(5, 1, 6))

    def theirs(x):
        return np.array([metrics.aggregate_mean(x[..., j]) for j in range(x.shape[-1])])

    def ours(x):
        return np.array([mean_of_task_means(x[..., j]) for j in range(x.shape[-1])])

    point, interval = _rliable_interval(scores, theirs, 300, 0)
    our_point, our_interval = interval_estimates(scores, ours, 300)
    np.testing.assert_array_equal(our_point, point)
    np.testing.assert_array_equal(our_interval, interval)


def test_the_callers_random_state_is_left_alone():
    np.random.seed(42)  # noqa: NPY002
    expected = np.random.random_sample()  # noqa: NPY002
    np.random.seed(42)  # noqa: NPY002
    interval_estimates(np.ones((4, 2)), np.mean, 20)
    assert np.random.random_sample() == expected  # noqa: NPY002


@pytest.mark.parametrize(
    ("scores", "options", "match"),
    [
        (np.ones(4), {}, "runs x tasks"),
        (np.ones((0, 3)), {}, "at least one run"),
        (np.ones((3, 2)), {"reps": 0}, "reps"),
        (np.ones((3, 2)), {"reps": 2.5}, "reps"),
        (np.ones((3, 2)), {"confidence": 1.0}, "confidence"),
        (np.ones((3, 2)), {"seed": -1}, "seed"),
    ],
)
def test_bad_input_is_a_value_error(scores, options, match):
    with pytest.raises(ValueError, match=match):
        interval_estimates(scores, np.mean, **{"reps": 10, **options})


def test_the_benchmarks_scores_need_no_rliable(monkeypatch):
    from observer_gym.train.experiments.benchmark.score import score_levels
    from observer_gym.train.experiments.benchmark.suite import References

    monkeypatch.setitem(sys.modules, "rliable", None)  # import rliable now raises
    refs = References(oracle=1.0, raw=0.2, idle=0.0, episodes=3)
    scores = score_levels(
        {"a": [0.5, 0.7, 0.9], "b": [0.1, 0.4, 0.3]}, {"a": refs, "b": refs}, "higher", reps=50
    )
    assert scores.aggregate.low <= scores.aggregate.value <= scores.aggregate.high
