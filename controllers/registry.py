"""``make_controller(name, env, **options)``: a controller designed for an env, by name."""

from __future__ import annotations

import inspect
from typing import Any

import gymnasium as gym

from observer_gym.controllers.base import StateFeedbackController
from observer_gym.controllers.lqr import LQRController
from observer_gym.controllers.mpc import MPCController
from observer_gym.controllers.pid import PIDController
from observer_gym.controllers.plant import BallTablePlant

__all__ = ["CONTROLLERS", "make_controller"]

CONTROLLERS: dict[str, type[StateFeedbackController]] = {
    "lqr": LQRController,
    "mpc": MPCController,
    "pid": PIDController,
}


def make_controller(name: str, env: gym.Env, **options: Any) -> StateFeedbackController:
    """The controller ``name`` (one of :data:`CONTROLLERS`) designed from ``env``'s nominal
    model; ``options`` go to its constructor. Unknown names and options raise ValueError
    listing the allowed ones."""
    if name not in CONTROLLERS:
        raise ValueError(f"unknown controller {name!r}; allowed: {', '.join(CONTROLLERS)}")
    cls = CONTROLLERS[name]
    allowed = [p for p in inspect.signature(cls).parameters if p != "plant"]
    unknown = sorted(set(options) - set(allowed))
    if unknown:
        raise ValueError(
            f"unknown option(s) {unknown} for controller {name!r}; allowed: {', '.join(allowed)}"
        )
    return cls(BallTablePlant.from_env(env), **options)
