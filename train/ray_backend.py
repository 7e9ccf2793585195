"""Episodes as Ray tasks: the ``ray`` backend of ``observer-gym compare`` and ``sweep``.

Each :class:`~observer_gym.train.run.EpisodeSpec` runs as one Ray task calling
:func:`~observer_gym.train.run.run_episode`, on a local Ray instance or on an existing
cluster (``ray start --head`` on one machine, ``ray start --address HEAD:6379`` on the
others; every node needs observer-gym installed). An episode's result depends only on its
spec, so the records equal the local backend's.

Ray is an optional dependency: ``pip install 'observer-gym[distributed]'``.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from tqdm import tqdm

from observer_gym.train.run import EpisodeSpec, run_episode

INSTALL_HINT = "pip install 'observer-gym[distributed]'"


def _import_ray() -> Any:
    try:
        import ray
    except ImportError as exc:
        raise ImportError(
            f"the ray backend needs Ray, which is not installed: {INSTALL_HINT}"
        ) from exc
    return ray


def local_cpus() -> int:
    """CPUs this process may use (its affinity mask where the OS has one)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def iter_episodes_ray(
    specs: Sequence[EpisodeSpec],
    address: str | None = None,
    run: Callable[[EpisodeSpec], Any] = run_episode,
) -> Iterator[tuple[int, Any]]:
    """``(index, run(specs[index]))`` for every spec as each finishes, computed as Ray
    tasks of one CPU each (``run``: a module-level function; the records of
    :func:`run_episode` by default).

    Connects to the cluster at ``address`` ("auto" for the one ``ray start`` set up on this
    machine, or ``HOST:PORT``), or, for None, starts a new local instance with this
    machine's CPUs (even if a cluster runs here; no dashboard, workers' output not
    forwarded). If Ray is already initialised in this process, its session is used as it
    is. Ray is shut down again only if this call started or connected it (a cluster keeps
    running; the driver disconnects), also when the caller stops iterating early (the
    tasks not finished are cancelled).

    Raises:
        ImportError: Ray is not installed (the message says how to install it).
    """
    ray = _import_ray()
    connected_here = not ray.is_initialized()
    if connected_here:
        if address is None:  # a private instance: only errors are worth showing
            ray.init(
                address="local",  # a new instance even if `ray start` runs a cluster here
                num_cpus=local_cpus(),
                include_dashboard=False,
                log_to_driver=False,
                logging_level=logging.ERROR,
            )
        else:  # a shared cluster: its warnings may concern this run
            ray.init(address=address, log_to_driver=False, logging_level=logging.WARNING)
    pending: list[Any] = []
    try:
        task = ray.remote(num_cpus=1)(run)
        refs = [task.remote(spec) for spec in specs]
        index_of = {ref: index for index, ref in enumerate(refs)}
        pending = list(refs)
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            for ref in done:
                yield index_of[ref], ray.get(ref)
    finally:
        for ref in pending:  # the caller stopped early (an error, Ctrl-C)
            ray.cancel(ref)
        if connected_here:
            ray.shutdown()


def run_episodes_ray(
    specs: Sequence[EpisodeSpec],
    address: str | None = None,
    progress: bool = True,
    desc: str = "compare",
) -> list[dict[str, Any]]:
    """The records of ``specs`` (:func:`run_episode`), in order, computed as Ray tasks of
    one CPU each, on the cluster at ``address`` or a new local instance
    (:func:`iter_episodes_ray`). A progress bar counts finished episodes.

    Raises:
        ImportError: Ray is not installed (the message says how to install it).
    """
    records: list[Any] = [None] * len(specs)
    episodes = iter_episodes_ray(specs, address)
    with tqdm(total=len(specs), unit="episode", desc=desc, disable=not progress) as bar:
        for index, record in episodes:
            records[index] = record
            bar.update(1)
    return records
