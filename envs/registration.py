"""The systems of observer-gym and their Gymnasium registration.

Each system has one record in :data:`SYSTEMS`. Its ``name`` is the name of its package in
every layer (``envs/<name>/``, ``estimation/<name>/``, ``controllers/<name>/``,
``train/core/tasks/<name>.py``); each layer finds its own part of a system there by that
name (:meth:`System.module`), or where the record's ``modules`` say for a system kept
outside the package.
Adding a system to the package is one package per layer and one record here; a system
from outside is one :func:`register_system` call.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, NamedTuple

import gymnasium as gym

if TYPE_CHECKING:
    from observer_gym.envs.core import CameraEnv

NAMESPACE = "observer_gym"
# where each layer keeps a system's part, under the package: <layer package>.<system name>
LAYERS = {
    "envs": "observer_gym.envs",
    "estimation": "observer_gym.estimation",
    "controllers": "observer_gym.controllers",
    "task": "observer_gym.train.core.tasks",
}


class System(NamedTuple):
    """One system: its package name in every layer and its Gymnasium registration."""

    name: str  # package name in every layer, "ball_table"
    env_id: str  # registered id, "observer_gym/BallTable-v0"
    entry_point: str  # "module:EnvClass"
    # Gymnasium's step limit; None: the env truncates itself (BallCatcher's limit is in
    # seconds, so its steps follow its options)
    max_episode_steps: int | None
    # (layer, module) pairs for a system kept outside the package: e.g.
    # (("estimation", "mylab.toy.estimation"), ...); a layer not named is looked up under
    # the package (LAYERS)
    modules: tuple[tuple[str, str], ...] = ()

    def module(self, layer: str) -> str:
        """The module of this system's part in ``layer`` (one of :data:`LAYERS`)."""
        if layer not in LAYERS:
            raise ValueError(f"unknown layer {layer!r}; allowed: {', '.join(LAYERS)}")
        return dict(self.modules).get(layer, f"{LAYERS[layer]}.{self.name}")

    @property
    def short_id(self) -> str:
        """The id without its namespace: "BallTable-v0"."""
        return self.env_id.split("/", 1)[-1]

    def env_class(self) -> type[CameraEnv]:
        """The env class of ``entry_point`` (imported on first use)."""
        module_name, class_name = self.entry_point.split(":")
        return getattr(importlib.import_module(module_name), class_name)


# the systems in order: the package's three, then any added by register_system
SYSTEMS: list[System] = [
    System(
        "ball_table",
        f"{NAMESPACE}/BallTable-v0",
        "observer_gym.envs.ball_table:BallTableEnv",
        500,
    ),
    System(
        "ball_catcher",
        f"{NAMESPACE}/BallCatcher-v1",
        "observer_gym.envs.ball_catcher:BallCatcherEnv",
        None,
    ),
    System(
        "target_follower",
        f"{NAMESPACE}/TargetFollower-v0",
        "observer_gym.envs.target_follower:TargetFollowerEnv",
        600,
    ),
]


# the package's own systems (SYSTEMS without those register_system added)
PACKAGE_SYSTEMS: tuple[System, ...] = tuple(SYSTEMS)

# ids no longer registered (without the namespace) -> what replaced them and why; gym.make
# of one raises Gymnasium's DeprecatedEnv, the commands say this (docs/envs.md)
RETIRED_IDS: dict[str, str] = {
    "BallCatcher-v0": (
        "BallCatcher-v1 replaced it after 0.2.0 (the reward shaping and the catch rule "
        "changed after 0.1.0; 0.2.0 ran v1's code under the old id); install the git tag "
        "v0.1.0 to reproduce 0.1.0's v0 results"
    ),
}


def register_envs() -> None:
    """Register every system's env with Gymnasium (once)."""
    for system in SYSTEMS:
        if system.env_id not in gym.registry:
            gym.register(
                id=system.env_id,
                entry_point=system.entry_point,
                max_episode_steps=system.max_episode_steps,
            )


def register_system(system: System) -> None:
    """Add ``system`` to :data:`SYSTEMS` and register its env with Gymnasium, so every
    layer and command takes it by name. ValueError if its name or env id is taken, or its
    ``modules`` name an unknown layer."""
    if not isinstance(system, System):
        raise ValueError(f"register_system takes a System record, got {type(system).__name__}")
    for taken in SYSTEMS:
        if system.name == taken.name or system.env_id == taken.env_id:
            raise ValueError(
                f"system {system.name!r} ({system.env_id}) clashes with the registered "
                f"{taken.name!r} ({taken.env_id}): name and env id must be new"
            )
    for layer, _ in system.modules:
        system.module(layer)  # ValueError for an unknown layer
    SYSTEMS.append(system)
    register_envs()


def unregister_system(name: str) -> None:
    """Remove the system ``name`` added by :func:`register_system` (and its Gymnasium id);
    the package's own systems stay. ValueError for an unknown or built-in name."""
    system = system_named(name)
    if system in PACKAGE_SYSTEMS:
        raise ValueError(f"{name!r} is one of the package's systems; only added ones go")
    SYSTEMS.remove(system)
    gym.registry.pop(system.env_id, None)


def system_named(name: str) -> System:
    """The system whose package is ``name`` ("ball_table"); ValueError listing them."""
    for system in SYSTEMS:
        if system.name == name:
            return system
    raise ValueError(f"unknown system {name!r}; known: {', '.join(s.name for s in SYSTEMS)}")


def system_for_id(env_id: str) -> System:
    """The system registered as ``env_id``, with or without the ``observer_gym/``
    namespace; ValueError naming the replacement of a retired id (:data:`RETIRED_IDS`),
    listing the known ids otherwise."""
    for system in SYSTEMS:
        if env_id in (system.env_id, system.short_id):
            return system
    retired = RETIRED_IDS.get(env_id.removeprefix(f"{NAMESPACE}/"))
    if retired is not None:
        raise ValueError(f"env {env_id!r} is no longer registered: {retired}")
    allowed = ", ".join(f"{s.short_id} (or {s.env_id})" for s in SYSTEMS)
    raise ValueError(f"unknown env {env_id!r}; allowed: {allowed}")


def system_of(env: gym.Env) -> System:
    """The system of ``env`` (any wrappers around it): the first whose env class
    ``env.unwrapped`` is an instance of, so a subclass of a system's env belongs to that
    system. ValueError naming the known systems otherwise."""
    base = env.unwrapped
    for system in SYSTEMS:
        if isinstance(base, system.env_class()):
            return system
    known = ", ".join(f"{s.short_id} ({s.entry_point})" for s in SYSTEMS)
    raise ValueError(f"{type(base).__name__} is not an env of a known system; known: {known}")
