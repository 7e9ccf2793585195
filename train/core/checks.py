"""The up-front checks of a request that every part of ``observer_gym.train`` shares: a
system's names, an observer by name, an env's options, the observer that feeds an agent,
seeds and backends, checked without importing PyTorch or stable-baselines3 and without
building an env. A controller is checked once, by the library
(:func:`observer_gym.train.experiments.request.check_controller`; a trained agent's run
folder by :func:`observer_gym.train.rl.run_dir.check_agent`), and a training request by
:mod:`observer_gym.train.rl.checks`.

The names a system takes (its task's observers with the ``obs_mode`` each makes the env
give, the task's ``ESTIMATE_OBSERVERS`` and the system's controllers) are read from its
packages in every layer (:mod:`observer_gym.train.core.systems`), so a system added
to :data:`observer_gym.envs.SYSTEMS` is taken with no edit here.

Env options are checked by the env's configuration class (``config_class.from_kwargs``,
the check the env runs first), which imports the env's module and PyBullet but builds no
world.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from observer_gym.envs import system_for_id
from observer_gym.envs.config import check_render_mode
from observer_gym.train.core import entries
from observer_gym.train.core.algorithms import ALGOS

if TYPE_CHECKING:
    from observer_gym.train.core.systems import SystemEntry

# a trained agent, wherever a controller is taken: "ppo:DIR, sac:DIR, td3:DIR"
AGENT_FORMS = ", ".join(f"{algo}:DIR" for algo in ALGOS)
# what else a controller can be: a saved stable-baselines3 model or an outside factory
OUTSIDE_FORMS = "ALGO:PATH.zip, an import path package.module:factory"
# the backends of train --seeds (as of compare)
BACKENDS = ("local", "ray")
RAY_INSTALL_HINT = "pip install 'observer-gym[distributed]'"
# gym.make's own keywords, which it does not pass to the env
GYM_MAKE_OPTIONS = ("max_episode_steps", "disable_env_checker")


def names_for(env_id: str) -> SystemEntry:
    """The names of the system registered as ``env_id``, read from its layers
    (:func:`observer_gym.train.core.systems.entry_for`); ValueError for an unknown
    env."""
    from observer_gym.train.core.systems import entry_for

    return entry_for(env_id)


def check_observer(env_id: str, observer: str) -> str:
    """The registered id of ``env_id`` after checking that ``observer`` is one of its
    task's observers, or an outside observer (:mod:`observer_gym.train.core.entries`) whose
    factory imports; ValueError naming what is allowed otherwise. A learned observer
    without PyTorch: :class:`~observer_gym.extras.ExtraNotInstalled` (an ImportError)
    naming ``pip install 'observer-gym[rl]'``."""
    system = system_for_id(env_id)
    env_id = system.env_id
    if observer not in names_for(env_id).observer_modes:
        entries.load_factory(_observer_plugin(env_id, observer))
    else:  # deferred: observer_env imports the estimation layer
        from observer_gym.train.core.observer_env import (
            require_observer_modules,
            resolve_observer,
        )

        # the learned ones: PyTorch
        require_observer_modules(system, resolve_observer(system, observer))
    return env_id


def _observer_plugin(env_id: str, observer: str) -> entries.Plugin:
    plugin = entries.find_plugin("observer", observer)
    if plugin is None:
        builtins = list(names_for(env_id).observers)
        raise ValueError(entries.unknown_message("observer", observer, env_id, builtins))
    return plugin


def observer_mode(env_id: str, observer: str) -> str:
    """The ``obs_mode`` of the env ``observer`` reads: a task observer's, or an outside
    observer's ("measurements" with the ``-measurements`` suffix, else "rgb")."""
    modes = names_for(env_id).observer_modes
    if observer in modes:
        return modes[observer]
    mode = _observer_plugin(env_id, observer).obs_mode
    assert mode is not None  # an observer plugin's is "rgb" or "measurements"
    return mode


# the observers without a pipeline, by the agent obs type that reads them
UNFILTERED_OBSERVERS = {"rgb": "pixels", "measurements": "detections"}


def frames_message(controller: str, observer: str) -> str:
    """Why a controller of the state layout cannot read ``observer``'s unfiltered camera
    output (frames, or the newest frame's detections)."""
    obs = {name: obs for obs, name in UNFILTERED_OBSERVERS.items()}.get(observer, "rgb")
    what = "camera frames" if obs == "rgb" else "the newest frame's detections, unfiltered"
    return (
        f"controller {controller!r} acts on the state layout; observer {observer!r} "
        f"gives {what}, which only an agent trained with --obs {obs} reads"
    )


def check_env_options(
    env_id: str, obs_mode: str, options: Mapping[str, Any], decided_by: str = "the observer"
) -> None:
    """ValueError unless the env builds with ``options`` (its ``gym.make`` keywords) and
    ``obs_mode``: no ``obs_mode`` among them (``decided_by`` decides it), a render mode
    the env has, and every other option a field of the env's configuration class with a
    value it takes (the message is the configuration's). Imports the env's module;
    builds no world."""
    options = dict(options)
    system = system_for_id(env_id)
    if "obs_mode" in options:
        raise ValueError(f"env option obs_mode is not allowed: {decided_by} decides it")
    env_class = system.env_class()
    try:
        check_render_mode(options.pop("render_mode", None), env_class.metadata)
        # deferred: observer_env imports the estimation layer
        from observer_gym.train.core.observer_env import check_gym_make_options

        check_gym_make_options(options)
        for key in GYM_MAKE_OPTIONS:
            options.pop(key, None)
        env_class.config_class.from_kwargs(obs_mode=obs_mode, **options)
    except ValueError as exc:
        raise ValueError(f"bad env option for {system.short_id}: {exc}") from None


def agent_observer(env_id: str, obs: str, estimate_from: str, observer: str | None = None) -> str:
    """The observer that feeds an agent trained with ``obs`` (as
    :func:`observer_gym.train.rl.agent_env.observer_for`): ``observer`` if given (with
    ``obs="estimate"`` only, one of the system's observers that estimate or an outside
    observer, :mod:`observer_gym.train.core.entries`), else the one
    ``estimate_from`` picks."""
    names = names_for(env_id)
    if observer is not None:
        estimating = [
            name
            for name, mode in names.observer_modes.items()
            if mode != "state" and name not in names.frame_observers
        ]
        if obs != "estimate":
            raise ValueError(f"an observer ({observer!r}) applies to --obs estimate only")
        if observer not in estimating:
            plugin = entries.find_plugin("observer", observer)
            if plugin is None:
                raise ValueError(
                    f"unknown estimating observer {observer!r} for "
                    f"{system_for_id(env_id).short_id}; allowed: {', '.join(estimating)}, or "
                    "an import path package.module:factory or installed entry point"
                )
            entries.load_factory(plugin)  # an outside observer: its factory must import
        return observer
    if obs == "state":
        return "oracle"
    if obs in UNFILTERED_OBSERVERS:
        return UNFILTERED_OBSERVERS[obs]
    return names.estimate_observers[estimate_from]


def check_seeds(seeds: Sequence[int]) -> tuple[int, ...]:
    """``seeds`` as a tuple of ints; ValueError unless they are at least one distinct
    integer >= 0."""
    seeds = list(seeds)
    if not seeds:
        raise ValueError("seeds must hold at least one seed")
    for seed in seeds:
        if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
            raise ValueError(f"seeds must be integers >= 0, got {seed!r}")
    duplicates = sorted({int(s) for s in seeds if seeds.count(s) > 1})
    if duplicates:
        raise ValueError(f"seeds must be distinct; {duplicates} appear more than once")
    return tuple(int(s) for s in seeds)


def check_backend(backend: str, workers: int | None, address: str | None) -> None:
    """ValueError for a bad ``backend`` ("local" or "ray"), ``workers`` (>= 1, local only)
    or ``address`` (ray only), or the ray backend without Ray installed."""
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; allowed: {', '.join(BACKENDS)}")
    if workers is not None and (
        isinstance(workers, bool) or not isinstance(workers, int) or workers < 1
    ):
        raise ValueError(f"workers must be an integer >= 1, got {workers!r}")
    if address is not None and backend != "ray":
        raise ValueError(f"address {address!r} is a Ray cluster's address: it needs backend 'ray'")
    if backend == "ray":
        if workers is not None:
            raise ValueError(
                "workers applies to the local backend only; with backend 'ray' the cluster's "
                "CPUs decide how many seeds train at once"
            )
        if importlib.util.find_spec("ray") is None:
            raise ValueError(f"backend 'ray' needs Ray, which is not installed: {RAY_INSTALL_HINT}")
