"""Every system as the ``observer-gym`` command sees it, assembled from its layers.

For each record of :data:`observer_gym.envs.SYSTEMS`, :func:`system_entries` gathers the
env id, the observers of its task (what ``run`` and ``compare`` take as ``--observer``),
the pipelines of ``observer_gym.estimation.<system>``, the controllers of
``observer_gym.controllers.<system>`` and the task module
``observer_gym.train.experiments.tasks.<system>``.
Reading them imports every layer; the command line takes its choices and help texts from
the light copy in :mod:`observer_gym.train.cli.checks`, which the tests hold equal to these.
"""

from __future__ import annotations

from types import ModuleType
from typing import NamedTuple

from observer_gym.controllers import controllers_of
from observer_gym.envs import SYSTEMS, System, system_for_id
from observer_gym.estimation.observer import observers_of_system
from observer_gym.train.experiments.tasks import task_of


class SystemEntry(NamedTuple):
    """One system across the layers."""

    system: System
    observers: tuple[str, ...]  # the task's OBSERVERS: oracle, kf, ..., pixels
    pipelines: tuple[str, ...]  # observer_gym.estimation.<system>.OBSERVERS
    controllers: tuple[str, ...]  # observer_gym.controllers.<system>.CONTROLLERS
    task: ModuleType  # observer_gym.train.experiments.tasks.<system>

    @property
    def env_id(self) -> str:
        return self.system.env_id


def system_entry(system: System) -> SystemEntry:
    """``system``'s entry, read from its package in every layer."""
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
    "BallTable-v0: lqr, mpc, pid; BallCatcher-v0: intercept; ..."."""
    return "; ".join(
        f"{entry.system.short_id}: {', '.join(getattr(entry, field))}" for entry in system_entries()
    )


def resolve_env_id(name: str) -> str:
    """The registered id for ``name``: a registered id or its name without the
    ``observer_gym/`` namespace. Anything else raises ``ValueError`` listing them."""
    return system_for_id(name).env_id
