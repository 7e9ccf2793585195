"""The env an observer gives: ``make_env(system, observer, env_kwargs)``, for a system
resolved once by its caller (:func:`observer_gym.envs.system_for_id`).

The same env serves ``observer-gym run`` and ``compare`` (with a controller on it) and
``train`` (with an agent on it). ``observer`` is one of the env's task's ``OBSERVERS``,
or an observer from outside the package (:mod:`observer_gym.train.core.entries`: an import
path or an installed entry point's name).
"""

from __future__ import annotations

import reprlib
from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.envs.registration import System
from observer_gym.estimation import VisionObserver
from observer_gym.estimation.observer import env_options_of, modules_needed
from observer_gym.extras import require_rl
from observer_gym.train.core import entries
from observer_gym.train.core.entry_guard import CheckedPipeline
from observer_gym.train.core.tasks import task_of


def observer_setup(system: System, observer: str) -> tuple[str, Mapping[str, Any] | None, Any]:
    """``(obs_mode, pipeline_options, plugin)`` of ``observer`` for ``system``: a task
    observer's env mode and default-pipeline options (None for one without a pipeline,
    "pixels") and plugin None; an outside observer's mode, None and its
    :class:`~observer_gym.train.core.entries.Plugin`. ValueError naming what is allowed for
    any other name."""
    observers = task_of(system).OBSERVERS
    if observer in observers:
        obs_mode, pipeline_options = observers[observer]
        return obs_mode, pipeline_options, None
    plugin = entries.find_plugin("observer", observer)
    if plugin is None:
        raise ValueError(
            entries.unknown_message("observer", observer, system.env_id, list(observers))
        )
    assert plugin.obs_mode is not None  # an observer plugin's is "rgb" or "measurements"
    return plugin.obs_mode, None, plugin


def require_observer_modules(system: System, observer: str) -> None:
    """:class:`~observer_gym.extras.ExtraNotInstalled` naming the install line if the task
    observer ``observer`` runs a pipeline that needs what this installation lacks (the
    learned observers need PyTorch: ``pip install 'observer-gym[rl]'``); nothing for the
    others, outside observers and unknown names (which :func:`observer_setup` refuses).
    Imports nothing it checks for."""
    setup = task_of(system).OBSERVERS.get(observer)
    if setup is None or setup[1] is None:
        return
    needed = modules_needed(system, setup[1].get("observer"))
    if needed:
        require_rl(f"observer {observer!r}", needed)


def observer_env_options(system: System, observer: str) -> dict[str, Any]:
    """The env options a task observer's pipeline needs to run (its system's estimation
    ``ENV_OPTIONS``, :func:`~observer_gym.estimation.observer.env_options_of`: e.g.
    BallCatcher's ``endpoint-measurements`` reads the hole's pixels,
    ``hole_measurements=True``); {} for the others and outside entries."""
    setup = task_of(system).OBSERVERS.get(observer)
    if setup is None or setup[1] is None:
        return {}
    return env_options_of(system, setup[1].get("observer"))


def with_observer_env_options(
    system: System, observer: str, env_kwargs: Mapping[str, Any] | None
) -> dict[str, Any]:
    """``env_kwargs`` with the options ``observer`` needs; a given option that contradicts
    one of them raises ValueError naming both."""
    given = dict(env_kwargs or {})
    for key, value in observer_env_options(system, observer).items():
        if key in given and given[key] != value:
            raise ValueError(
                f"observer {observer!r} needs the env option {key}={value!r}; "
                f"got {key}={given[key]!r}"
            )
        given[key] = value
    return given


def check_gym_make_options(options: Mapping[str, Any]) -> None:
    """ValueError naming the option unless ``max_episode_steps`` is an integer >= 1 (or
    None) and ``disable_env_checker`` true or false, as ``gym.make`` takes them."""
    steps = options.get("max_episode_steps")
    if steps is not None and (
        isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 1
    ):
        raise ValueError(
            f"max_episode_steps must be an integer >= 1 (steps), got {reprlib.repr(steps)}"
        )
    checker = options.get("disable_env_checker", False)
    if not isinstance(checker, bool):
        raise ValueError(f"disable_env_checker must be true or false, got {reprlib.repr(checker)}")


def make_env(
    system: System,
    observer: str,
    env_kwargs: Mapping[str, Any] | None = None,
    observer_options: Mapping[str, Any] | None = None,
) -> gym.Env:
    """The env for ``observer``: the state env for "oracle", the camera frames for an
    observer without a pipeline ("pixels"), else the env in the observer's obs_mode
    wrapped in :class:`VisionObserver` with the observer's pipeline (a task observer's
    default pipeline with its options and ``observer_options``; an outside observer's
    factory called with ``observer_options``). ``env_kwargs`` go to ``gym.make``, with
    the env options the observer needs (:func:`observer_env_options`)."""
    obs_mode, _, _ = observer_setup(system, observer)
    env_kwargs = with_observer_env_options(system, observer, env_kwargs)
    check_gym_make_options(env_kwargs)
    env = gym.make(system.env_id, obs_mode=obs_mode, **env_kwargs)
    return wrap_observer(env, system, observer, observer_options)


def wrap_observer(
    env: gym.Env,
    system: System,
    observer: str,
    observer_options: Mapping[str, Any] | None = None,
) -> gym.Env:
    """``env`` (made in ``observer``'s obs_mode) wrapped in the :class:`VisionObserver` of
    ``observer``'s pipeline (see :func:`make_env`), or unchanged for "oracle" and an
    observer without a pipeline; ``env`` is closed if this fails."""
    try:
        _, pipeline_options, plugin = observer_setup(system, observer)
        if plugin is not None:
            pipeline = entries.build(plugin, env.unwrapped, observer_options)
            base: Any = env.unwrapped  # an observer-gym env: it has the state layout
            state_dim = base.state_space.shape[0]
            checked = CheckedPipeline(pipeline, plugin, state_dim)
            return VisionObserver(env, pipeline=checked, name=observer)
        if observer == "oracle" or pipeline_options is None:
            if observer_options:
                raise ValueError(
                    f"observer {observer!r} takes no options, got {dict(observer_options)}"
                )
            return env
        return VisionObserver(env, **{**dict(pipeline_options), **dict(observer_options or {})})
    except BaseException:
        env.close()
        raise
