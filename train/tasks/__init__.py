"""Per-env pieces of ``observer-gym run``: observers, metrics, summary rows and plots.

``observer_gym.train.run`` runs episodes of any registered env the same way; what is
measured and drawn depends on the task, so each env id maps in :data:`TASKS` to a module
of this package that provides the :class:`Task` interface (``ball_table.py`` is the
reference). Adding an env to ``observer-gym run`` is one module and one line here.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import ModuleType
from typing import Any, Protocol

# registered env id -> module implementing Task
TASKS: dict[str, str] = {
    "observer_gym/BallTable-v0": "observer_gym.train.tasks.ball_table",
    "observer_gym/BallCatcher-v0": "observer_gym.train.tasks.ball_catcher",
    "observer_gym/TargetFollower-v0": "observer_gym.train.tasks.target_follower",
}


class Task(Protocol):
    """What a task module defines.

    - ``OBSERVERS``: observer name -> (the env's ``obs_mode``, options of the env's default
      VisionObserver pipeline, or None for no observer); "oracle" maps to ("state", {})
      and is not wrapped; "pixels" maps to ("rgb", None): the camera frames themselves,
      which only an agent trained with ``--obs rgb`` reads.
    - ``ESTIMATE_OBSERVERS``: the observer an agent trained with ``--obs estimate`` reads,
      by where the estimate comes from ("measurements" or "rgb").
    - ``CONFIG``: task constants recorded in results.json (e.g. tolerances).
    - ``SUMMARY_ROWS``: summary key -> (label, unit, scale from SI to the unit, digits).
    - ``COMPARE_METRICS``: the metrics of ``observer-gym compare``'s table, key -> (label,
      unit, scale, digits, "lower" or "higher" is better); the first is the primary one,
      whose paired observer - oracle difference gets a column. An optional
      ``compare_extras(episode)`` adds per-episode numbers derived for the table.
    - ``episode_metrics(record)``: one episode's metrics from the record of
      :func:`observer_gym.train.run.run_episode`.
    - ``summarize(episodes)``: the summary of a list of ``episode_metrics`` dicts; it has
      every key of ``SUMMARY_ROWS``.
    - ``plot(records, observer, out_dir)``: writes the plots; returns their file names.
    """

    OBSERVERS: Mapping[str, tuple[str, Mapping[str, Any] | None]]
    ESTIMATE_OBSERVERS: Mapping[str, str]
    CONFIG: Mapping[str, Any]
    SUMMARY_ROWS: Mapping[str, tuple[str, str, float, int]]

    def episode_metrics(self, record: Mapping[str, Any]) -> dict[str, Any]: ...

    def summarize(self, episodes: Sequence[Mapping[str, Any]]) -> dict[str, Any]: ...

    def plot(
        self, records: Sequence[Mapping[str, Any]], observer: str, out_dir: Path
    ) -> list[str]: ...


def task_for(env_id: str) -> ModuleType:
    """The task module of the registered ``env_id``; ValueError if it has none."""
    if env_id not in TASKS:
        raise ValueError(
            f"observer-gym run does not know {env_id!r} yet; known: {', '.join(TASKS)}"
        )
    return importlib.import_module(TASKS[env_id])
