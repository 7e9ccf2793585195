"""Every system as the ``observer-gym`` command sees it, assembled from its layers.

For each record of :data:`observer_gym.envs.SYSTEMS`, :func:`system_entries` gathers the
env id, the observers of its task (what ``run`` and ``compare`` take as ``--observer``),
the pipelines of ``observer_gym.estimation.<system>``, the controllers of
``observer_gym.controllers.<system>`` and the task module
``observer_gym.train.core.tasks.<system>``.
Reading them imports every layer (about 1.5 s); the command line reads them when it
checks a request or shows ``--help``, not to parse its arguments.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from typing import NamedTuple

from observer_gym.controllers import controllers_of
from observer_gym.envs import SYSTEMS, System, system_for_id
from observer_gym.estimation.observer import observers_of_system
from observer_gym.train.core.tasks import Task, task_of


class SystemEntry(NamedTuple):
    """One system across the layers."""

    system: System
    observers: tuple[str, ...]  # the task's OBSERVERS: oracle, kf, ..., pixels
    pipelines: tuple[str, ...]  # observer_gym.estimation.<system>.OBSERVERS
    controllers: tuple[str, ...]  # observer_gym.controllers.<system>.CONTROLLERS
    task: Task  # observer_gym.train.core.tasks.<system>

    @property
    def env_id(self) -> str:
        return self.system.env_id

    @property
    def observer_modes(self) -> Mapping[str, str]:
        """The task's observers: name -> the ``obs_mode`` each makes the env give."""
        return {name: mode for name, (mode, _) in self.task.OBSERVERS.items()}

    @property
    def frame_observers(self) -> tuple[str, ...]:
        """The observers that give the camera frames unfiltered ("pixels")."""
        return tuple(
            name
            for name, (mode, pipeline) in self.task.OBSERVERS.items()
            if pipeline is None and mode != "state"
        )

    @property
    def estimate_observers(self) -> Mapping[str, str]:
        """The task's ``ESTIMATE_OBSERVERS``: what an agent trained with ``--obs estimate``
        reads, by where the estimate comes from."""
        return dict(self.task.ESTIMATE_OBSERVERS)


@functools.cache
def system_entry(system: System) -> SystemEntry:
    """``system``'s entry, read from its package in every layer (once per process)."""
    task = task_of(system)
    return SystemEntry(
        system,
        tuple(task.OBSERVERS),
        tuple(observers_of_system(system)),
        tuple(controllers_of(system)),
        task,
    )


def system_entries() -> tuple[SystemEntry, ...]:
    """The entry of every system, in the order of :data:`SYSTEMS`."""
    return tuple(system_entry(system) for system in SYSTEMS)


def entry_for(env_id: str) -> SystemEntry:
    """The entry of the system registered as ``env_id`` (namespace optional)."""
    return system_entry(system_for_id(env_id))


def _union(groups: list[tuple[str, ...]]) -> tuple[str, ...]:
    return tuple(dict.fromkeys(name for group in groups for name in group))


def observer_choices() -> tuple[str, ...]:
    """Every system's observers, each name once, in order of first appearance."""
    return _union([entry.observers for entry in system_entries()])


def controller_choices() -> tuple[str, ...]:
    """Every system's controllers, each name once, in order of first appearance."""
    return _union([entry.controllers for entry in system_entries()])


def per_env(field: str) -> str:
    """``field`` ("observers" or "controllers") of every system, as help text:
    "BallTable-v0: lqr, mpc, pid; BallCatcher-v1: intercept; ..."."""
    return "; ".join(
        f"{entry.system.short_id}: {', '.join(getattr(entry, field))}" for entry in system_entries()
    )


def resolve_env_id(name: str) -> str:
    """The registered id for ``name``: a registered id or its name without the
    ``observer_gym/`` namespace. Anything else raises ``ValueError`` listing them."""
    return system_for_id(name).env_id
