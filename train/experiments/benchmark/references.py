"""A suite level's reference values, measured: the oracle observer with the reference
controller (score 1), the raw camera baseline with it, and doing nothing (the idle
controller), each on the level's official seeds, run exactly as a benchmark entry's
episodes are (:func:`~observer_gym.train.experiments.sweep.sweep_episode`, the headline
metric by :func:`~observer_gym.train.experiments.benchmark.records.metric_value`).

``benchmarks/benchmark_references.py`` calls :func:`measure_level` for every level and
writes the means into the suite file. Neither baseline uses a filter, so the package's
filters can change without the references going stale.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from observer_gym.envs import system_for_id
from observer_gym.train.core.observer_env import resolve_observer
from observer_gym.train.experiments.benchmark.records import metric_value
from observer_gym.train.experiments.benchmark.suite import Level, References, SystemSuite
from observer_gym.train.experiments.episode import EpisodeSpec, iter_episodes
from observer_gym.train.experiments.request import resolve_controller
from observer_gym.train.experiments.sweep import sweep_episode

IDLE = "observer_gym.train.experiments.benchmark.idle:make_idle"


class LevelReferences(NamedTuple):
    """A level's reference values and the per-episode values they are the means of."""

    references: References
    oracle: np.ndarray
    raw: np.ndarray
    idle: np.ndarray


def episode_values(
    suite: SystemSuite, level: Level, observer: str, controller: str, seeds: Sequence[int],
    workers: int = 1,
) -> np.ndarray:  # fmt: skip
    """The headline metric of each episode of ``observer`` + ``controller`` on ``level``
    with ``seeds``, as a benchmark run measures it."""
    system = system_for_id(suite.env_id)  # resolved once for the episodes
    observer_entry = resolve_observer(system, observer)
    controller_entry = resolve_controller(system, controller)
    specs = [
        EpisodeSpec.of_entries(
            system, observer_entry, controller_entry, seed, env_kwargs=level.env_options
        )
        for seed in seeds
    ]
    values = np.zeros(len(specs))
    metric = suite.metric.name
    for index, episode in iter_episodes(specs, workers, sweep_episode):
        where = f"level {level.name!r}, seed {specs[index].seed}"
        values[index] = metric_value(episode["metrics"].get(metric), metric, where)
    return values


def measure_level(suite: SystemSuite, level: Level, workers: int = 1) -> LevelReferences:
    """The level's :class:`References` on its official seeds, with the values behind them."""
    seeds = level.seeds(suite.episodes)
    oracle = episode_values(suite, level, "oracle", suite.controller, seeds, workers)
    raw = episode_values(suite, level, suite.floor_observer, suite.controller, seeds, workers)
    idle = episode_values(suite, level, "oracle", IDLE, seeds, workers)
    refs = References(float(np.mean(oracle)), float(np.mean(raw)), float(np.mean(idle)), len(seeds))
    return LevelReferences(refs, oracle, raw, idle)
