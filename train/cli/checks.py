"""The up-front checks of the ``observer-gym`` command: a request's env options,
observers, controllers, trained agents and training settings, checked without importing
PyTorch or stable-baselines3 and without building an env.

The names a system takes (its task's observers with the ``obs_mode`` each makes the env
give, the task's ``ESTIMATE_OBSERVERS`` and the system's controllers) are read from its
packages in every layer (:mod:`observer_gym.train.core.systems`), so a system added
to :data:`observer_gym.envs.SYSTEMS` is taken with no edit here. The library checks every
request again against the layers, with the same messages
(:func:`observer_gym.train.experiments.request.check_pair`).

Env options are checked by the env's configuration class (``config_class.from_kwargs``,
the check the env runs first), which imports the env's module and PyBullet but builds no
world.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from observer_gym.envs import SYSTEMS, system_for_id
from observer_gym.envs.config import check_render_mode
from observer_gym.extras import require_rl
from observer_gym.train.core import entries
from observer_gym.train.core.controller_entries import check_policy_file, is_policy_file
from observer_gym.train.rl.hyperparams import ALGOS, resolve_hyperparams

if TYPE_CHECKING:
    from observer_gym.train.core.systems import SystemEntry
from observer_gym.train.rl.run_dir import (
    check_new_run_folder,
    check_new_seeds_folder,
    model_files,
    parse_agent_spec,
    read_config,
)

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
    env_id = system_for_id(env_id).env_id
    if observer not in names_for(env_id).observer_modes:
        entries.load_factory(_observer_plugin(env_id, observer))
    else:  # deferred: observer_env imports the estimation layer
        from observer_gym.train.core.observer_env import require_observer_modules

        require_observer_modules(env_id, observer)  # the learned ones: PyTorch
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


def check_controller(controller: str, env_id: str, observer: str) -> None:
    """ValueError unless ``controller`` acts on ``observer``'s output in ``env_id`` (as
    :func:`observer_gym.train.experiments.request.check_controller`): one of the system's
    controllers
    (another system's is refused naming those that fit), which read the state layout
    (any observer but one giving camera frames), or a trained agent ``ALGO:DIR`` whose
    folder holds a run of ``env_id`` with a model to load, trained on what ``observer``
    gives."""
    system = system_for_id(env_id)
    names = names_for(system.env_id)
    reads_frames = observer in names.frame_observers
    agent_spec = parse_agent_spec(controller)
    if agent_spec is not None and is_policy_file(agent_spec[1]):
        check_policy_file(controller, agent_spec[1])
        agent_spec = None
    elif agent_spec is None and controller not in names.controllers:
        plugin = entries.find_plugin("controller", controller)
        if plugin is not None:
            entries.load_factory(plugin)
            agent_spec = None
    if agent_spec is None:
        if controller not in names.controllers and not _outside(controller):
            fits = ", ".join([*names.controllers, AGENT_FORMS, OUTSIDE_FORMS])
            for other in SYSTEMS:
                if other != system and controller in names_for(other.env_id).controllers:
                    raise ValueError(
                        f"controller {controller!r} does not fit {system.short_id}: it is made "
                        f"for a {other.short_id} env; {system.short_id} takes: {fits}"
                    )
            raise ValueError(f"unknown controller {controller!r}; allowed: {fits}")
        if reads_frames:
            raise ValueError(frames_message(controller, observer))
        return
    check_agent(controller, system.env_id, reads_frames, observer)


def _outside(controller: str) -> bool:
    """Whether ``controller`` is a stable-baselines3 zip or an outside controller."""
    spec = parse_agent_spec(controller)
    if spec is not None:
        return is_policy_file(spec[1])
    return entries.find_plugin("controller", controller) is not None


def frames_message(controller: str, observer: str) -> str:
    """Why a controller of the state layout cannot read ``observer``'s camera frames."""
    return (
        f"controller {controller!r} acts on the state layout; observer {observer!r} "
        "gives camera frames, which only an agent trained with --obs rgb reads"
    )


def check_agent(controller: str, env_id: str, reads_frames: bool, observer: str) -> None:
    """ValueError unless the trained agent ``controller`` (``ALGO:DIR``) is a run of
    ``env_id`` with a model to load, trained on camera frames iff ``reads_frames``;
    first, :class:`~observer_gym.extras.ExtraNotInstalled` without stable-baselines3 and
    PyTorch to load it."""
    spec = parse_agent_spec(controller)
    assert spec is not None, f"{controller!r} is not ALGO:DIR"  # the callers' check
    require_rl(f"agent {controller!r}")  # stable-baselines3 and PyTorch load it
    algo, run_dir = spec
    agent = read_config(run_dir, algo=algo)
    model_files(run_dir)
    if agent["env_id"] != env_id:
        raise ValueError(f"agent {controller!r} was trained on {agent['env_id']}, not {env_id}")
    if (agent["obs"] == "rgb") != reads_frames:
        wants = "observer 'pixels'" if agent["obs"] == "rgb" else "an observer but 'pixels'"
        raise ValueError(
            f"agent {controller!r} was trained with --obs {agent['obs']}: it needs {wants}, "
            f"got {observer!r}"
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
    if obs == "rgb":
        return "pixels"
    return names.estimate_observers[estimate_from]


def training_overrides(
    hyperparams: Mapping[str, Any] | None,
    timesteps: int | None = None,
    n_envs: int | None = None,
    vec_env: str | None = None,
) -> dict[str, Any]:
    """The hyperparameter overrides of a training run: ``hyperparams`` (dotted keys) and
    the options that set training keys (``n_timesteps``, ``n_envs``, ``vec_env``)."""
    overrides = dict(hyperparams or {})
    for key, value in (("n_timesteps", timesteps), ("n_envs", n_envs), ("vec_env", vec_env)):
        if value is not None:
            overrides[key] = value
    return overrides


def check_training_request(
    env_id: str,
    algo: str,
    obs: str,
    estimate_from: str,
    out_dir: str | Path,
    overrides: Mapping[str, Any],
    env_options: Mapping[str, Any],
    tensorboard: bool,
    observer: str | None = None,
) -> dict[str, Any]:
    """The hyperparameters of a new ``observer-gym train`` run resolved from the YAML
    and ``overrides`` (:func:`~observer_gym.train.rl.hyperparams.resolve_hyperparams`: the
    training keys checked, not yet the algorithm's, which need stable-baselines3), after
    checking ``env_options`` over the YAML's ``env_kwargs`` with the obs_mode of ``obs``,
    that ``out_dir`` holds no run yet and that TensorBoard is installed if asked for."""
    env_id = system_for_id(env_id).env_id
    params = resolve_hyperparams(env_id, algo, obs, overrides)
    env_kwargs = {**params["env_kwargs"], **dict(env_options)}
    obs_mode = observer_mode(env_id, agent_observer(env_id, obs, estimate_from, observer))
    check_env_options(env_id, obs_mode, env_kwargs, decided_by="--obs")
    check_new_run_folder(out_dir)
    if tensorboard and importlib.util.find_spec("tensorboard") is None:
        raise ValueError(
            "--tensorboard needs the tensorboard package: pip install 'observer-gym[tensorboard]'"
        )
    return params


# --- train --seeds ----------------------------------------------------------------------
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


def check_seeds_folder(out_dir: str | Path) -> None:
    """ValueError if ``out_dir`` already holds a run, single or multi-seed
    (:func:`~observer_gym.train.rl.run_dir.check_new_seeds_folder`)."""
    check_new_seeds_folder(out_dir)
