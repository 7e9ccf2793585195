"""``make_controller(name, env, **options)``: a controller designed for an env, by name."""

from __future__ import annotations

import inspect
from collections.abc import Callable
from typing import Any

import gymnasium as gym

from observer_gym.controllers.ball_catcher.intercept import InterceptController
from observer_gym.controllers.ball_catcher.plant import BallCatcherPlant
from observer_gym.controllers.ball_table.plant import BallTablePlant
from observer_gym.controllers.base import Controller
from observer_gym.controllers.lqr import LQRController
from observer_gym.controllers.mpc import MPCController
from observer_gym.controllers.pid import PIDController
from observer_gym.controllers.target_follower.plant import TargetFollowerPlant
from observer_gym.controllers.target_follower.vtc import VisualTrackingController

__all__ = ["CONTROLLERS", "make_controller"]

# name -> (controller class, the function that builds its first argument, the design
# input, from an env; it raises ValueError for an env the controller is not made for).
CONTROLLERS: dict[str, tuple[type[Controller], Callable[[gym.Env], Any]]] = {
    "lqr": (LQRController, BallTablePlant.from_env),
    "mpc": (MPCController, BallTablePlant.from_env),
    "pid": (PIDController, BallTablePlant.from_env),
    "intercept": (InterceptController, BallCatcherPlant.from_env),
    "vtc": (VisualTrackingController, TargetFollowerPlant.from_env),
}


def make_controller(name: str, env: gym.Env, **options: Any) -> Controller:
    """The controller ``name`` (one of :data:`CONTROLLERS`) designed from ``env``'s nominal
    model; ``options`` go to its constructor. Unknown names and options raise ValueError
    listing the allowed ones."""
    if name not in CONTROLLERS:
        raise ValueError(f"unknown controller {name!r}; allowed: {', '.join(CONTROLLERS)}")
    cls, design_input = CONTROLLERS[name]
    allowed = list(inspect.signature(cls).parameters)[1:]
    unknown = sorted(set(options) - set(allowed))
    if unknown:
        raise ValueError(
            f"unknown option(s) {unknown} for controller {name!r}; allowed: {', '.join(allowed)}"
        )
    return cls(design_input(env), **options)
