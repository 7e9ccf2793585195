"""Per-env pieces of ``observer-gym run``: observers, metrics, summary rows and plots.

``observer_gym.train.experiments.run`` runs episodes of any registered env the same way; what is
measured and drawn depends on the task: each system of :data:`observer_gym.envs.SYSTEMS`
has the module of this package named after it (``ball_table.py`` is the reference), which
provides the :class:`Task` interface.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, cast

from observer_gym.envs import System


class Task(Protocol):
    """What a task module defines.

    - ``OBSERVERS``: observer name -> (the env's ``obs_mode``, options of the env's default
      VisionObserver pipeline, or None for no observer); "oracle" maps to ("state", {})
      and is not wrapped; "pixels" maps to ("rgb", None): the camera frames themselves,
      which only an agent trained with ``--obs rgb`` reads; "detections" maps to
      ("measurements", None): the newest delivered frame's perfect-detector report, which
      only an agent trained with ``--obs measurements`` reads.
    - ``ESTIMATE_OBSERVERS``: the observer an agent trained with ``--obs estimate`` reads,
      by where the estimate comes from ("measurements" or "rgb").
    - ``CONFIG``: task constants recorded in results.json (e.g. tolerances).
    - ``SUMMARY_ROWS``: summary key -> (label, unit, scale from SI to the unit, digits).
    - ``COMPARE_METRICS``: the metrics of ``observer-gym compare``'s table, key -> (label,
      unit, scale, digits, "lower" or "higher" is better); the first is the primary one,
      whose paired observer - oracle difference gets a column. An optional
      ``compare_extras(episode)`` adds per-episode numbers derived for the table. An
      optional ``COMPARE_COUNTS``, episode key -> (label, values in order), adds a column
      beside the primary metric counting the pair's episodes of each value (BallCatcher's
      misses by reason).
    - ``episode_metrics(record)``: one episode's metrics from the record of
      :func:`observer_gym.train.experiments.episode.run_episode`.
    - ``summarize(episodes)``: the summary of a list of ``episode_metrics`` dicts; it has
      every key of ``SUMMARY_ROWS``.
    - ``plot(records, observer, out_dir)``: writes the plots; returns their file names.
    """

    # read-only, as a module's constants are read: a task's own may be any Mapping
    @property
    def OBSERVERS(self) -> Mapping[str, tuple[str, Mapping[str, Any] | None]]: ...

    @property
    def ESTIMATE_OBSERVERS(self) -> Mapping[str, str]: ...

    @property
    def CONFIG(self) -> Mapping[str, Any]: ...

    @property
    def SUMMARY_ROWS(self) -> Mapping[str, tuple[str, str, float, int]]: ...

    @property
    def COMPARE_METRICS(self) -> Mapping[str, tuple[str, str, float, int, str]]: ...

    def episode_metrics(self, record: Mapping[str, Any]) -> dict[str, Any]: ...

    def summarize(self, episodes: Sequence[Mapping[str, Any]]) -> dict[str, Any]: ...

    def plot(
        self, records: Sequence[Mapping[str, Any]], observer: str, out_dir: Path
    ) -> list[str]: ...


def task_of(system: System) -> Task:
    """The task module of ``system``: ``observer_gym.train.core.tasks.<system name>``."""
    return cast(Task, importlib.import_module(system.module("task")))


if TYPE_CHECKING:  # mypy holds each of the package's tasks to Task (.ci/typecheck.py)
    from observer_gym.train.core.tasks import ball_catcher, ball_table, target_follower

    BALL_CATCHER: Task = ball_catcher
    BALL_TABLE: Task = ball_table
    TARGET_FOLLOWER: Task = target_follower
