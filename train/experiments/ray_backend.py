"""The ``ray`` backend of ``observer-gym compare`` and ``sweep``: each
:class:`~observer_gym.train.experiments.episode.EpisodeSpec` runs as one Ray task calling
:func:`~observer_gym.train.experiments.episode.run_episode`
(:func:`~observer_gym.train.reports.ray_tasks.iter_tasks_ray`: a local Ray instance or an
existing cluster, docs/compare.md). An episode's result depends only on its spec, so the
records equal the local backend's.

Ray is an optional dependency: ``pip install 'observer-gym[distributed]'``.
"""

from __future__ import annotations

from collections.abc import Callable, Generator, Sequence
from typing import Any

from observer_gym.train.experiments.episode import EpisodeSpec, run_episode
from observer_gym.train.reports.ray_tasks import iter_tasks_ray, run_tasks_ray


def iter_episodes_ray(
    specs: Sequence[EpisodeSpec],
    address: str | None = None,
    run: Callable[[EpisodeSpec], Any] = run_episode,
) -> Generator[tuple[int, Any], None, None]:
    """``(index, run(specs[index]))`` for every spec as each finishes, as Ray tasks
    (:func:`iter_tasks_ray`; ``run``: a module-level function, :func:`run_episode` by
    default)."""
    return iter_tasks_ray(run, [(spec,) for spec in specs], address)


def run_episodes_ray(
    specs: Sequence[EpisodeSpec],
    address: str | None = None,
    progress: bool = True,
    desc: str = "compare",
) -> list[dict[str, Any]]:
    """The records of ``specs`` (:func:`run_episode`), in order, computed as Ray tasks of
    one CPU each (:func:`run_tasks_ray`).

    Raises:
        ImportError: Ray is not installed (the message says how to install it).
    """
    return run_tasks_ray(
        run_episode, [(spec,) for spec in specs], address, progress, desc, "episode"
    )
