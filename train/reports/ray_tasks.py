"""Ray tasks, the runner under the ``ray`` backend of ``observer-gym compare``, ``sweep``
and ``train --seeds``: :func:`iter_tasks_ray` and :func:`run_tasks_ray` run a module-level
function once per argument tuple, each call a Ray task of one CPU, on a local Ray instance
or on an existing cluster (``ray start --head`` on one machine, ``ray start --address
HEAD:6379`` on the others, with ``RAY_AUTH_MODE=token`` and the head's
``~/.ray/auth_token`` on every node and for the command: docs/compare.md; every node
needs observer-gym installed). A task whose node dies is run again by Ray elsewhere.
:func:`local_cpus` counts the CPUs this process may use (the local backends' default
number of workers).

The episodes' tasks are in :mod:`observer_gym.train.experiments.ray_backend`, the seeds'
of a multi-seed training run in :mod:`observer_gym.train.rl.seeds`.

Ray is an optional dependency: ``pip install 'observer-gym[distributed]'``.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import tempfile
from collections.abc import Callable, Generator, Sequence
from typing import Any

from observer_gym.train.core.checks import RAY_INSTALL_HINT
from observer_gym.train.reports.progress import progress_bar

CANCEL_WAIT_S = 60.0  # how long cancelled tasks get to end before Ray shuts down


def _import_ray() -> Any:
    try:
        import ray
    except ImportError as exc:
        raise ImportError(
            f"the ray backend needs Ray, which is not installed: {RAY_INSTALL_HINT}"
        ) from exc
    return ray


def local_cpus() -> int:
    """CPUs this process may use (its affinity mask where the OS has one)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


AUTH_HINT = (
    "if it runs, it may use token authentication, which 'ray start --head' turns on when "
    "the head has a ~/.ray/auth_token (any local Ray run writes one): run with "
    "RAY_AUTH_MODE=token, the cluster's token in ~/.ray/auth_token here "
    "(docs/compare.md, 'On a Ray cluster')"
)


def _connect(ray: Any, address: str) -> None:
    """``ray.init`` on the cluster at ``address``; a cluster that cannot be reached (or
    refuses this process's token) is a ``ConnectionError`` of one line saying what to
    do. Ray's core prints a warning per connection retry on the standard error (file
    descriptor 2); those are held back while connecting and shown only if it connects."""
    held = tempfile.TemporaryFile()
    stderr = os.dup(2)
    sys.stderr.flush()
    os.dup2(held.fileno(), 2)
    try:
        ray.init(address=address, log_to_driver=False, logging_level=logging.WARNING)
    except (ConnectionError, ray.exceptions.AuthenticationError) as exc:
        why = " ".join(str(exc).split())[:300]
        hint = "" if os.environ.get("RAY_AUTH_MODE") == "token" else f"; {AUTH_HINT}"
        raise ConnectionError(
            f"could not connect to the Ray cluster at {address} ({why}){hint}"
        ) from None
    else:
        held.seek(0)
        os.write(stderr, held.read())
    finally:
        sys.stderr.flush()
        os.dup2(stderr, 2)
        os.close(stderr)
        held.close()


def local_runtime_env() -> dict[str, Any]:
    """The runtime environment of a private local instance: this process's import path
    (outside the Python installation) as the workers' PYTHONPATH, so an outside observer
    or controller named by import path imports in every task as it does here. On a
    cluster, install such a package on every node instead."""
    installed = {os.path.realpath(p) for p in (sys.prefix, sys.base_prefix, sys.exec_prefix)}
    own = [
        os.path.abspath(path)
        for path in sys.path
        if path and not any(os.path.realpath(path).startswith(prefix) for prefix in installed)
    ]
    paths = list(
        dict.fromkeys([*own, *filter(None, os.environ.get("PYTHONPATH", "").split(os.pathsep))])
    )
    return {"env_vars": {"PYTHONPATH": os.pathsep.join(paths)}} if paths else {}


def iter_tasks_ray(
    function: Callable[..., Any],
    arguments: Sequence[tuple[Any, ...]],
    address: str | None = None,
) -> Generator[tuple[int, Any], None, None]:
    """``(index, function(*arguments[index]))`` for every entry as each finishes, each a
    Ray task of one CPU (``function`` must be importable on every node).

    Connects to the cluster at ``address`` ("auto" for the one ``ray start`` set up on this
    machine, or ``HOST:PORT``), or, for None, starts a new local instance with this
    machine's CPUs (even if a cluster runs here; no dashboard, workers' output not
    forwarded). If Ray is already initialised in this process, its session is used as it
    is. Ray is shut down again only if this call started or connected it (a cluster keeps
    running; the driver disconnects). When the caller stops iterating early (an error,
    Ctrl-C), the tasks still running are cancelled: Ray raises ``KeyboardInterrupt`` in
    them, so they end as they would here.

    Raises:
        ImportError: Ray is not installed (the message says how to install it).
        ConnectionError: no cluster at ``address`` accepts this process (the message
            says what to do when token authentication is the reason).
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
                runtime_env=local_runtime_env(),
            )
        else:  # a shared cluster: its warnings may concern this run
            _connect(ray, address)
    pending: list[Any] = []
    try:
        task = ray.remote(num_cpus=1)(function)
        refs = [task.remote(*args) for args in arguments]
        index_of = {ref: index for index, ref in enumerate(refs)}
        pending = list(refs)
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            for ref in done:
                yield index_of[ref], ray.get(ref)
    finally:
        if pending:  # the caller stopped early
            for ref in pending:
                ray.cancel(ref)
            ray.wait(pending, num_returns=len(pending), timeout=CANCEL_WAIT_S)
        if connected_here:
            ray.shutdown()


def run_tasks_ray(
    function: Callable[..., Any],
    arguments: Sequence[tuple[Any, ...]],
    address: str | None = None,
    progress: bool = True,
    desc: str = "ray",
    unit: str = "task",
) -> list[Any]:
    """``function(*args)`` for every ``args`` of ``arguments``, in order
    (:func:`iter_tasks_ray`); a progress bar counts finished tasks."""
    results: list[Any] = [None] * len(arguments)
    # closing: an error or Ctrl-C here cancels the tasks at once, not when GC finds the
    # generator
    tasks = contextlib.closing(iter_tasks_ray(function, arguments, address))
    with (
        tasks as finished,
        progress_bar(total=len(arguments), unit=unit, desc=desc, disable=not progress) as bar,
    ):
        for index, result in finished:
            results[index] = result
            bar.update(1)
    return results
