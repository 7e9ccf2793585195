"""Controllers by name, per system: ``make_controller(name, env, **options)``.

Each system's controllers are the ``CONTROLLERS`` of its package
``observer_gym.controllers.<system>`` (name -> :class:`ControllerDesign`), found by the
system's name (:data:`observer_gym.envs.SYSTEMS`). A name that belongs to another system
is refused naming the controllers that fit the env.
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable, Mapping
from typing import Any, NamedTuple

import gymnasium as gym

from observer_gym.controllers.base import Controller
from observer_gym.envs import SYSTEMS, System, system_for_id, system_of

__all__ = [
    "ControllerDesign",
    "check_controller_fits",
    "controllers_for",
    "controllers_of",
    "design_controller",
    "make_controller",
]


class ControllerDesign(NamedTuple):
    """How a controller is made: ``controller(design_input(env), **options)``."""

    controller: Callable[..., Controller]  # a class: controller(plant, **options)
    # builds the controller's first argument (its plant) from an env; raises ValueError
    # for an env the controller is not made for
    design_input: Callable[[gym.Env], Any]
    summary: str = ""  # one line for 'observer-gym list'


def controllers_of(system: System) -> Mapping[str, ControllerDesign]:
    """The controllers of ``system``: the ``CONTROLLERS`` of its package."""
    return importlib.import_module(system.module("controllers")).CONTROLLERS


def controllers_for(env_id: str) -> Mapping[str, ControllerDesign]:
    """The controllers of the system registered as ``env_id`` (with or without the
    ``observer_gym/`` namespace)."""
    return controllers_of(system_for_id(env_id))


def check_controller_fits(name: str, system: System, others: str = "") -> ControllerDesign:
    """The design of controller ``name`` of ``system``. ValueError otherwise: for another
    system's controller, naming the system it is made for and those that fit; for an
    unknown name, listing those that fit (followed by ``others``, e.g. ", or ...")."""
    own = controllers_of(system)
    if name in own:
        return own[name]
    fits = ", ".join(own)
    for other in SYSTEMS:
        if other != system and name in controllers_of(other):
            raise ValueError(
                f"controller {name!r} does not fit {system.short_id}: it is made for a "
                f"{other.short_id} env; {system.short_id} takes: {fits}{others}"
            )
    raise ValueError(f"unknown controller {name!r}; allowed: {fits}{others}")


def make_controller(name: str, env: gym.Env, /, **options: Any) -> Controller:
    """The controller ``name`` of ``env``'s system designed from ``env``'s nominal model;
    ``options`` go to its constructor. A controller of another system, an unknown name, an
    unknown option or an ``env`` that is no gymnasium env raise ValueError naming what is
    allowed (as does a bad option value, from the constructor).

    Example, the LQR on the kf's estimate of BallTable:
        >>> import gymnasium as gym
        >>> import numpy as np
        >>> from observer_gym.controllers import make_controller
        >>> from observer_gym.estimation import VisionObserver
        >>> env = VisionObserver(gym.make("observer_gym/BallTable-v0", obs_mode="measurements"),
        ...                      observer="kf")
        >>> controller = make_controller("lqr", env)
        >>> estimate, info = env.reset(seed=0)
        >>> for _ in range(150):  # 3 s
        ...     action, _ = controller.predict(estimate, deterministic=True)
        ...     estimate, reward, terminated, truncated, info = env.step(action)
        >>> distance_m = np.hypot(*info["state"][:2])  # the ball from the table's centre
        >>> bool(distance_m < 1e-3)
        True
        >>> env.close()
    """
    if not isinstance(name, str):
        raise ValueError(f"make_controller: name = {name!r}, must be a controller's name (str)")
    if not isinstance(env, gym.Env):
        raise ValueError(
            f"make_controller: env = {env!r}, must be a gymnasium env of a registered system "
            f"({', '.join(s.env_id for s in SYSTEMS)}), e.g. gym.make(...)"
        )
    return design_controller(name, check_controller_fits(name, system_of(env)), env, options)


def design_controller(
    name: str, design: ControllerDesign, env: gym.Env, options: Mapping[str, Any] | None = None
) -> Controller:
    """The controller ``name`` of ``design`` (one of the env's system's controllers, found
    by the caller) designed from ``env``'s nominal model with ``options``; an unknown
    option raises ValueError naming those allowed (as does a bad value, from the
    constructor)."""
    cls, design_input, _ = design
    options = dict(options or {})
    allowed = list(inspect.signature(cls).parameters)[1:]
    unknown = sorted(set(options) - set(allowed))
    if unknown:
        raise ValueError(
            f"unknown option(s) {unknown} for controller {name!r}; allowed: {', '.join(allowed)}"
        )
    return cls(design_input(env), **options)
