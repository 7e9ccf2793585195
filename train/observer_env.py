"""The env an observer of a task gives: ``make_env(env_id, observer, env_kwargs)``.

The same env serves ``observer-gym run`` and ``compare`` (with a controller on it) and
``train`` (with an agent on it).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import gymnasium as gym

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.estimation import VisionObserver
from observer_gym.train.tasks import task_for


def make_env(
    env_id: str,
    observer: str,
    env_kwargs: Mapping[str, Any] | None = None,
    observer_options: Mapping[str, Any] | None = None,
) -> gym.Env:
    """The env for ``observer`` (one of the env's task's ``OBSERVERS``): the state env for
    "oracle", the camera frames for an observer without a pipeline ("pixels"), else the
    env in the observer's obs_mode wrapped in :class:`VisionObserver` with the observer's
    pipeline options and ``observer_options``. ``env_kwargs`` go to ``gym.make``."""
    observers = task_for(env_id).OBSERVERS
    if observer not in observers:
        raise ValueError(
            f"unknown observer {observer!r} for {env_id}; allowed: {', '.join(observers)}"
        )
    obs_mode, _ = observers[observer]
    env = gym.make(env_id, obs_mode=obs_mode, **dict(env_kwargs or {}))
    return wrap_observer(env, env_id, observer, observer_options)


def wrap_observer(
    env: gym.Env,
    env_id: str,
    observer: str,
    observer_options: Mapping[str, Any] | None = None,
) -> gym.Env:
    """``env`` (made in ``observer``'s obs_mode) wrapped in the :class:`VisionObserver` of
    ``observer``'s pipeline options (and ``observer_options``, passed to the pipeline), or
    unchanged for "oracle" and an observer without a pipeline; ``env`` is closed if this
    fails."""
    _, pipeline_options = task_for(env_id).OBSERVERS[observer]
    if observer == "oracle" or pipeline_options is None:
        if observer_options:
            raise ValueError(
                f"observer {observer!r} takes no options, got {dict(observer_options)}"
            )
        return env
    try:
        return VisionObserver(env, **{**dict(pipeline_options), **dict(observer_options or {})})
    except BaseException:
        env.close()
        raise
