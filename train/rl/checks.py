"""The up-front checks of a training request (``observer-gym train``,
:func:`observer_gym.train.rl.training.train_agent`): its hyperparameters, env options,
output folder and TensorBoard, checked without importing PyTorch or stable-baselines3
and without building an env."""

from __future__ import annotations

import importlib.util
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from observer_gym.envs import system_for_id
from observer_gym.train.core.checks import agent_observer, check_env_options, observer_mode
from observer_gym.train.rl.hyperparams import resolve_hyperparams
from observer_gym.train.rl.run_dir import check_new_run_folder, check_new_seeds_folder


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


def check_seeds_folder(out_dir: str | Path) -> None:
    """ValueError if ``out_dir`` already holds a run, single or multi-seed
    (:func:`~observer_gym.train.rl.run_dir.check_new_seeds_folder`)."""
    check_new_seeds_folder(out_dir)
