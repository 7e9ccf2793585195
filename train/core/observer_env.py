"""The env an observer gives: ``make_env(system, observer, env_kwargs)``, for a system
and an observer resolved once by their caller (:func:`observer_gym.envs.system_for_id`,
:func:`resolve_observer`).

The same env serves ``observer-gym run`` and ``compare`` (with a controller on it) and
``train`` (with an agent on it). An :class:`ObserverEntry` is one of the env's task's
``OBSERVERS`` or an observer from outside the package
(:mod:`observer_gym.train.core.entries`: an import path or an installed entry point's
name), resolved into strings and dicts: it pickles, so it travels to worker processes
and Ray tasks inside an episode's spec and is not looked up again there.
"""

from __future__ import annotations

import reprlib
from collections.abc import Mapping
from typing import Any, NamedTuple

import gymnasium as gym
import numpy as np

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.envs.registration import System
from observer_gym.estimation import VisionObserver
from observer_gym.estimation.observer import env_options_of, modules_needed
from observer_gym.extras import require_rl
from observer_gym.train.core import entries
from observer_gym.train.core.entries import Plugin
from observer_gym.train.core.entry_guard import CheckedPipeline
from observer_gym.train.core.tasks import Task, task_of


class ObserverEntry(NamedTuple):
    """One observer, resolved for one system (:func:`resolve_observer`)."""

    name: str  # as the results name it
    obs_mode: str  # the env's obs_mode it reads
    # a package observer's default-pipeline options; None: no pipeline ("oracle" has {}),
    # or an outside observer
    pipeline_options: dict[str, Any] | None
    plugin: Plugin | None  # an outside observer's entry
    # its factory's keyword arguments (an outside observer), or options over its
    # pipeline's (a package observer's, e.g. r_scale)
    options: dict[str, Any]
    # the env options its pipeline needs to run (its system's estimation ENV_OPTIONS,
    # e.g. BallCatcher's endpoint-measurements reads the hole's pixels)
    env_options: dict[str, Any] = {}  # noqa: RUF012 (a NamedTuple default, never mutated)

    @property
    def reads_pixels(self) -> bool:
        """Whether it hands the env's own observation on: "pixels" (camera frames) and
        "detections" (the perfect detector's report), which no state-layout controller reads."""
        return self.plugin is None and self.pipeline_options is None and self.obs_mode != "state"

    def with_options(self, options: Mapping[str, Any] | None) -> ObserverEntry:
        """This entry with ``options`` (its factory's or over its pipeline's)."""
        return self._replace(options=dict(options or {}))

    def record(self) -> dict[str, Any]:
        """What results record of it: env mode, pipeline options, an outside entry."""
        record: dict[str, Any] = {
            "obs_mode": self.obs_mode,
            "pipeline_options": self.pipeline_options,
        }
        if self.plugin is not None:
            record["entry"] = self.plugin.describe(self.options)
        return record


def resolve_observer(
    system: System,
    observer: str,
    options: Mapping[str, Any] | None = None,
    task: Task | None = None,
) -> ObserverEntry:
    """The :class:`ObserverEntry` of ``observer`` for ``system`` (whose task is ``task``,
    looked up if not given): a task observer's env mode, default-pipeline options and the
    env options it needs; an outside observer's mode and
    :class:`~observer_gym.train.core.entries.Plugin` (nothing imported). ValueError naming
    what is allowed for any other name."""
    observers = (task_of(system) if task is None else task).OBSERVERS
    if observer in observers:
        obs_mode, pipeline = observers[observer]
        pipeline_options = None if pipeline is None else dict(pipeline)
        env_options = (
            {} if pipeline_options is None
            else env_options_of(system, pipeline_options.get("observer"))
        )  # fmt: skip
        return ObserverEntry(
            observer, obs_mode, pipeline_options, None, dict(options or {}), env_options
        )
    plugin = entries.find_plugin("observer", observer)
    if plugin is None:
        raise ValueError(
            entries.unknown_message("observer", observer, system.env_id, list(observers))
        )
    assert plugin.obs_mode is not None  # an observer plugin's is "rgb" or "measurements"
    return ObserverEntry(observer, plugin.obs_mode, None, plugin, dict(options or {}))


def require_observer_modules(system: System, observer: ObserverEntry) -> None:
    """:class:`~observer_gym.extras.ExtraNotInstalled` naming the install line if the task
    observer ``observer`` runs a pipeline that needs what this installation lacks (the
    learned observers need PyTorch: ``pip install 'observer-gym[rl]'``); nothing for the
    others and outside observers. Imports nothing it checks for."""
    if observer.pipeline_options is None:
        return
    needed = modules_needed(system, observer.pipeline_options.get("observer"))
    if needed:
        require_rl(f"observer {observer.name!r}", needed)


def observer_env_options(system: System, observer: str) -> dict[str, Any]:
    """The env options the observer named ``observer`` needs (:attr:`ObserverEntry.env_options`),
    for a name read back from a results folder; {} for outside entries and unknown names."""
    task = task_of(system)
    if observer not in task.OBSERVERS:
        return {}
    return dict(resolve_observer(system, observer, task=task).env_options)


def with_observer_env_options(
    observer: ObserverEntry, env_kwargs: Mapping[str, Any] | None
) -> dict[str, Any]:
    """``env_kwargs`` with the options ``observer`` needs; a given option that contradicts
    one of them raises ValueError naming both."""
    given = dict(env_kwargs or {})
    for key, value in observer.env_options.items():
        if key in given and given[key] != value:
            raise ValueError(
                f"observer {observer.name!r} needs the env option {key}={value!r}; "
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
    observer: ObserverEntry,
    env_kwargs: Mapping[str, Any] | None = None,
) -> gym.Env:
    """The env for ``observer`` (resolved for ``system``: :func:`resolve_observer`): the
    state env for "oracle", the camera frames for an observer without a pipeline
    ("pixels"), else the env in the observer's obs_mode wrapped in :class:`VisionObserver`
    with the observer's pipeline (a task observer's default pipeline with its options and
    the entry's; an outside observer's factory called with the entry's options).
    ``env_kwargs`` go to ``gym.make``, with the env options the observer needs
    (:func:`with_observer_env_options`). Looks nothing up by name."""
    env_kwargs = with_observer_env_options(observer, env_kwargs)
    check_gym_make_options(env_kwargs)
    env = gym.make(system.env_id, obs_mode=observer.obs_mode, **env_kwargs)
    return wrap_observer(env, observer)


def wrap_observer(env: gym.Env, observer: ObserverEntry) -> gym.Env:
    """``env`` (made in ``observer``'s obs_mode) wrapped in the :class:`VisionObserver` of
    ``observer``'s pipeline (see :func:`make_env`), or unchanged for "oracle" and an
    observer without a pipeline; ``env`` is closed if this fails."""
    try:
        if observer.plugin is not None:
            pipeline = entries.build(observer.plugin, env.unwrapped, observer.options)
            base: Any = env.unwrapped  # an observer-gym env: it has the state layout
            state_dim = base.state_space.shape[0]
            checked = CheckedPipeline(pipeline, observer.plugin, state_dim)
            return VisionObserver(env, pipeline=checked, name=observer.name)
        if observer.name == "oracle" or observer.pipeline_options is None:
            if observer.options:
                raise ValueError(
                    f"observer {observer.name!r} takes no options, got {observer.options}"
                )
            return env
        return VisionObserver(env, **{**observer.pipeline_options, **observer.options})
    except BaseException:
        env.close()
        raise
