"""A fourth system kept outside the package, for the tests: a camera above a point mass.

``toy/PointMass-v0``: a small red sphere moves on the plane z = 0 under a commanded
acceleration, with random velocity kicks; a camera 0.8 m above watches it. Each layer's
part is one module of this package (``env``, ``estimation``, ``controllers``, ``task``)
and :data:`SYSTEM` says where; ``register()`` adds it to observer-gym
(:func:`observer_gym.envs.register_system`). Nothing in the package names it: the tests
register it and run it through the env suite and every command
(tests/toy_system/test_toy_system.py).
"""

from __future__ import annotations

from observer_gym.envs import SYSTEMS, System, register_system

SYSTEM = System(
    "point_mass",
    "toy/PointMass-v0",
    "toy_system.env:PointMassEnv",
    100,
    modules=(
        ("envs", "toy_system.env"),
        ("estimation", "toy_system.estimation"),
        ("controllers", "toy_system.controllers"),
        ("task", "toy_system.task"),
    ),
)


def register() -> None:
    """Add the system to observer-gym (once per process)."""
    if SYSTEM not in SYSTEMS:
        register_system(SYSTEM)
