"""Ray tasks: the ``ray`` backend of ``observer-gym compare`` and ``train --seeds``.

Each :class:`~observer_gym.train.run.EpisodeSpec` runs as one Ray task calling
:func:`~observer_gym.train.run.run_episode` (and each seed of a multi-seed training run
as one calling :func:`~observer_gym.train.training.continue_run`:
:mod:`observer_gym.train.seeds`), on a local Ray instance or on an existing
cluster (``ray start --head`` on one machine, ``ray start --address HEAD:6379`` on the
others; every node needs observer-gym installed). An episode's result depends only on its
spec, so the records equal the local backend's.

Ray is an optional dependency: ``pip install 'observer-gym[distributed]'``.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Sequence
from typing import Any

from tqdm import tqdm

from observer_gym.train.run import EpisodeSpec, run_episode

INSTALL_HINT = "pip install 'observer-gym[distributed]'"
CANCEL_WAIT_S = 60.0  # how long cancelled tasks get to end before Ray shuts down


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


def run_tasks_ray(
    function: Callable[..., Any],
    arguments: Sequence[tuple[Any, ...]],
    address: str | None = None,
    progress: bool = True,
    desc: str = "ray",
    unit: str = "task",
) -> list[Any]:
    """``function(*args)`` for every ``args`` of ``arguments``, in order, each a Ray task of
    one CPU (``function`` must be importable on every node).

    Connects to the cluster at ``address`` ("auto" for the one ``ray start`` set up on this
    machine, or ``HOST:PORT``), or, for None, starts a new local instance with this
    machine's CPUs (even if a cluster runs here; no dashboard, workers' output not
    forwarded). If Ray is already initialised in this process, its session is used as it
    is. Ray is shut down again only if this call started or connected it (a cluster keeps
    running; the driver disconnects). A progress bar counts finished tasks. Ctrl-C (or
    any error while waiting) cancels the tasks still running: Ray raises
    ``KeyboardInterrupt`` in them.

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
    try:
        task = ray.remote(num_cpus=1)(function)
        refs = [task.remote(*args) for args in arguments]
        try:
            with tqdm(total=len(refs), unit=unit, desc=desc, disable=not progress) as bar:
                pending = list(refs)
                while pending:
                    done, pending = ray.wait(pending, num_returns=1)
                    bar.update(len(done))
        except BaseException:
            for ref in refs:
                ray.cancel(ref)  # KeyboardInterrupt in the task: it ends as it would here
            ray.wait(refs, num_returns=len(refs), timeout=CANCEL_WAIT_S)
            raise
        return list(ray.get(refs))
    finally:
        if connected_here:
            ray.shutdown()
