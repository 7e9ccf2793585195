"""The systems of observer-gym and their Gymnasium registration.

Each system has one record in :data:`SYSTEMS`. Its ``name`` is the name of its package in
every layer (``envs/<name>/``, ``estimation/<name>/``, ``controllers/<name>/``,
``train/experiments/tasks/<name>.py``); each layer finds its own part of a system there by that
name.
Adding a system is one package per layer and one record here.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, NamedTuple

import gymnasium as gym

if TYPE_CHECKING:
    from observer_gym.envs.core import CameraEnv

NAMESPACE = "observer_gym"


class System(NamedTuple):
    """One system: its package name in every layer and its Gymnasium registration."""

    name: str  # package name in every layer, "ball_table"
    env_id: str  # registered id, "observer_gym/BallTable-v0"
    entry_point: str  # "module:EnvClass"
    max_episode_steps: int

    @property
    def short_id(self) -> str:
        """The id without its namespace: "BallTable-v0"."""
        return self.env_id.split("/", 1)[-1]

    def env_class(self) -> type[CameraEnv]:
        """The env class of ``entry_point`` (imported on first use)."""
        module_name, class_name = self.entry_point.split(":")
        return getattr(importlib.import_module(module_name), class_name)


SYSTEMS: tuple[System, ...] = (
    System(
        "ball_table",
        f"{NAMESPACE}/BallTable-v0",
        "observer_gym.envs.ball_table:BallTableEnv",
        500,
    ),
    System(
        "ball_catcher",
        f"{NAMESPACE}/BallCatcher-v0",
        "observer_gym.envs.ball_catcher:BallCatcherEnv",
        200,
    ),
    System(
        "target_follower",
        f"{NAMESPACE}/TargetFollower-v0",
        "observer_gym.envs.target_follower:TargetFollowerEnv",
        600,
    ),
)


def register_envs() -> None:
    """Register every system's env with Gymnasium (once)."""
    for system in SYSTEMS:
        if system.env_id not in gym.registry:
            gym.register(
                id=system.env_id,
                entry_point=system.entry_point,
                max_episode_steps=system.max_episode_steps,
            )


def system_named(name: str) -> System:
    """The system whose package is ``name`` ("ball_table"); ValueError listing them."""
    for system in SYSTEMS:
        if system.name == name:
            return system
    raise ValueError(f"unknown system {name!r}; known: {', '.join(s.name for s in SYSTEMS)}")


def system_for_id(env_id: str) -> System:
    """The system registered as ``env_id``, with or without the ``observer_gym/``
    namespace; ValueError listing the known ids otherwise."""
    for system in SYSTEMS:
        if env_id in (system.env_id, system.short_id):
            return system
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
