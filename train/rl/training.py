"""``observer-gym train``: a stable-baselines3 agent on an env's state, an observer's
estimate or the camera frames; and ``--resume`` of an interrupted run.

A run's folder holds:

- ``config.json``: everything resolved (env, obs, observer, hyperparameters, seed, action
  bounds, package versions, the command line), written before training starts;
- ``checkpoints/``: periodic checkpoints written atomically (:mod:`.checkpoints`);
- ``eval.csv``: the evaluation curve (deterministic policy, the same ``eval_episodes``
  episodes every time), ``curve.png`` its plot;
- ``logs/<segment>/progress.csv`` (SB3's training log, and TensorBoard events with
  ``--tensorboard``), ``monitor/`` (every training episode's return and length);
- when finished, ``model.zip``, ``vecnormalize.npz`` (plain arrays:
  :mod:`.normalizer_file`) and ``final.json`` (their sha256, checked whenever the agent
  is loaded); ``state.json`` says the status
  (running, interrupted, finished), the timestep count, the throughput and the
  ``writer`` (PID, host, process start time). A run killed with SIGKILL stays "running"
  there; readers report it as "killed" once its writer is gone
  (:func:`observer_gym.train.rl.run_dir.read_state`), and ``--resume`` then removes the temp
  files it left and says so (an :class:`~observer_gym.train.reports.outputs.OutputFolderWarning`).

Seeds: the training envs of a run with seed s reset first with 1,000,000 + 1,000 s + rank
(after a resume, plus the timestep count), and evaluation uses 2,000,000 + 1,000 s, so
the episodes that ``observer-gym run`` and ``evaluate`` score (seeds 0, 1, ...) are never
trained on. On CPU, two runs with the same seed and settings give identical models.
"""

from __future__ import annotations

import dataclasses
import shutil
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from gymnasium import spaces

from observer_gym.train.reports.folder_lock import folder_lock
from observer_gym.train.reports.outputs import (
    OneLineWarning,
    OutputFolderWarning,
    output_folder,
    package_versions,
    remove_stale_temps,
    to_jsonable,
)
from observer_gym.train.rl.agent_env import ImageOptions, make_agent_env, observer_for
from observer_gym.train.rl.learning import eval_csv_problem, learn
from observer_gym.train.rl.run_dir import (
    CHECKPOINTS,
    LATEST,
    STATE_FILE,
    check_new_run_folder,
    check_resumable,
    intact_checkpoint,
    killed_text,
    read_config,
    read_state,
    write_config,
)


class CheckpointWarning(OneLineWarning):
    """A checkpoint passed over when resuming (a file missing or damaged)."""


def train_agent(
    env_id: str,
    algo: str,
    obs: str,
    out_dir: str | Path,
    timesteps: int | None = None,
    seed: int = 0,
    estimate_from: str = "measurements",
    observer: str | None = None,
    n_envs: int | None = None,
    vec_env: str | None = None,
    hyperparams: Mapping[str, Any] | None = None,
    env_kwargs: Mapping[str, Any] | None = None,
    randomize: Mapping[str, Any] | None = None,
    tensorboard: bool = False,
    progress: bool = True,
    cli_args: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Train ``algo`` on ``env_id`` reading ``obs``; returns the final ``state.json``.

    Args:
        env_id: a registered id, with or without ``observer_gym/``.
        algo: ppo, sac or td3.
        obs: state, estimate or rgb (see :mod:`observer_gym.train.rl.agent_env`).
        out_dir: the run's folder; it must not hold a run already (use ``resume``).
        timesteps: env steps to train for (None: the YAML's ``n_timesteps``).
        seed: the run's seed (>= 0).
        estimate_from: for ``obs="estimate"``, measurements or rgb: picks the system's
            default estimating observer for that input.
        observer: for ``obs="estimate"``, the observer by name instead (any of the task's
            ``OBSERVERS`` that estimate: kf, kf-latency-measurements, ...).
        n_envs, vec_env: override the YAML's.
        hyperparams: dotted-key overrides of the YAML's values.
        env_kwargs: ``gym.make`` options (not obs_mode: ``obs`` decides it), over the
            YAML's ``env_kwargs``.
        randomize: options each training episode draws anew, ``{KEY: {"low": LOW,
            "high": HIGH}}`` or ``{KEY: {"choices": [A, B]}}``, none of ``env_kwargs``
            (:mod:`observer_gym.train.rl.randomize`); recorded in config.json, continued by
            a resume; the evaluation curve and every loaded agent use the fixed options.
        tensorboard: also write TensorBoard logs (needs the tensorboard package).
        progress: show SB3's progress bar.
        cli_args: the command line, recorded in config.json.

    The run holds ``out_dir``'s lock (:mod:`observer_gym.train.reports.folder_lock`) from
    before it writes config.json until it ends, however it ends.

    Raises:
        ValueError: any bad argument or hyperparameter, or a run already in ``out_dir``
            (also one written there by another command since the first check: an
            :class:`~observer_gym.train.reports.outputs.OutputFolderError`), before anything
            is written.
        FolderBusyError: another command holds ``out_dir``; nothing was written.
    """
    config = run_config(
        env_id,
        algo,
        obs,
        out_dir,
        timesteps=timesteps,
        seed=seed,
        estimate_from=estimate_from,
        observer=observer,
        n_envs=n_envs,
        vec_env=vec_env,
        hyperparams=hyperparams,
        env_kwargs=env_kwargs,
        randomize=randomize,
        tensorboard=tensorboard,
        cli_args=cli_args,
    )
    out_dir = Path(out_dir)
    # the folder is this run's alone from before config.json is written until training
    # ends; whether it holds a run is checked again under the lock
    with output_folder(out_dir, "train", marker=False, check=check_new_run_folder):
        write_config(out_dir, config)
        return learn(out_dir, config, progress=progress)


def run_config(
    env_id: str,
    algo: str,
    obs: str,
    out_dir: str | Path,
    timesteps: int | None = None,
    seed: int = 0,
    estimate_from: str = "measurements",
    observer: str | None = None,
    n_envs: int | None = None,
    vec_env: str | None = None,
    hyperparams: Mapping[str, Any] | None = None,
    env_kwargs: Mapping[str, Any] | None = None,
    randomize: Mapping[str, Any] | None = None,
    tensorboard: bool = False,
    cli_args: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The ``config.json`` of a new run (the arguments of :func:`train_agent`), after
    its checks (:func:`check_training`) and a probe env that gives the action bounds;
    nothing is written.

    Raises:
        ValueError: any bad argument or hyperparameter.
    """
    env_id, feeding, params, env_kwargs, randomize = check_training(
        env_id,
        algo,
        obs,
        out_dir,
        timesteps=timesteps,
        seed=seed,
        estimate_from=estimate_from,
        observer=observer,
        n_envs=n_envs,
        vec_env=vec_env,
        hyperparams=hyperparams,
        env_kwargs=env_kwargs,
        randomize=randomize,
        tensorboard=tensorboard,
    )
    probe = make_agent_env(
        env_id,
        obs,
        estimate_from,
        env_kwargs,
        params["image"],
        observer,
        params["features"],
        measurement_stack=params["measurement_stack"],
    )
    try:  # the action bounds a loaded agent maps back to, and a check that the env builds
        action_space = probe.unwrapped.action_space
    finally:
        probe.close()
    if not isinstance(action_space, spaces.Box):
        raise TypeError(f"{env_id}: the action space must be a Box, not {action_space}")
    if randomize:  # every draw must keep the agent's spaces (RandomizedEnv requires it)
        from observer_gym.train.rl.randomize import check_spaces

        check_spaces(
            lambda drawn: make_agent_env(
                env_id,
                obs,
                estimate_from,
                {**env_kwargs, **drawn},
                params["image"],
                observer,
                params["features"],
                measurement_stack=params["measurement_stack"],
            ),
            randomize,
        )
    encoder = params["image"].get("encoder") if obs == "rgb" else None
    recorded = {}  # the frame encoder's file, which a loaded agent checks
    if encoder is not None:
        from observer_gym.train.rl.pixel_encoder import encoder_sha256  # deferred: PyTorch

        recorded["encoder_sha256"] = encoder_sha256(encoder)
    return to_jsonable(
        {
            "env_id": env_id,
            "algo": algo,
            "obs": obs,
            "estimate_from": estimate_from if obs == "estimate" else None,
            "observer": feeding,
            "env_kwargs": env_kwargs,
            **({"randomize": randomize} if randomize else {}),
            "seed": int(seed),
            "hyperparams": params,
            "tensorboard": bool(tensorboard),
            "action_low": action_space.low,
            "action_high": action_space.high,
            "versions": package_versions(),
            "cli_args": cli_args,
            **recorded,
        }
    )


def write_run_config(run_dir: Path, config: Mapping[str, Any]) -> None:
    """Create ``run_dir`` (removing stale temps there) and write ``config`` as its
    config.json, atomically, with its sha256 (:func:`~observer_gym.train.rl.run_dir.
    write_config`), holding the folder's lock; :class:`~observer_gym.train.reports.
    outputs.OutputFolderError` if it holds a run already."""
    with output_folder(run_dir, "train", marker=False, check=check_new_run_folder):
        write_config(run_dir, config)


def check_training(
    env_id: str,
    algo: str,
    obs: str,
    out_dir: str | Path,
    timesteps: int | None = None,
    seed: int = 0,
    estimate_from: str = "measurements",
    observer: str | None = None,
    n_envs: int | None = None,
    vec_env: str | None = None,
    hyperparams: Mapping[str, Any] | None = None,
    env_kwargs: Mapping[str, Any] | None = None,
    randomize: Mapping[str, Any] | None = None,
    tensorboard: bool = False,
) -> tuple[str, str, dict[str, Any], dict[str, Any], dict[str, dict[str, Any]]]:
    """The checks of :func:`train_agent` (same arguments), which build no env and write
    nothing: the env, ``obs`` and ``estimate_from``, the seed, the env options, the
    output folder and TensorBoard (:func:`observer_gym.train.rl.checks.check_training_request`),
    then the hyperparameters' keys against the algorithm's constructor (this imports
    stable-baselines3) and, for ``obs="rgb"``, the image options.

    Returns:
        The registered env id, the observer that feeds the agent, the resolved
        hyperparameters, the env's ``gym.make`` options (the YAML's with
        ``env_kwargs`` over them) and the checked randomisation
        (:func:`~observer_gym.train.rl.randomize.check_randomize`: every key an option of
        the env, none of ``env_kwargs``, both ends of every range taken by the env).

    Raises:
        ValueError: naming the bad argument or hyperparameter and what is allowed.
    """
    from observer_gym.train.core.checks import observer_mode
    from observer_gym.train.core.systems import resolve_env_id
    from observer_gym.train.rl.checks import check_training_request, training_overrides
    from observer_gym.train.rl.hyperparams import check_algorithm_keys
    from observer_gym.train.rl.randomize import check_randomize

    env_id = resolve_env_id(env_id)
    feeding = observer_for(env_id, obs, estimate_from, observer)
    if int(seed) != seed or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    overrides = training_overrides(hyperparams, timesteps, n_envs, vec_env)
    params = check_training_request(
        env_id,
        algo,
        obs,
        estimate_from,
        out_dir,
        overrides,
        env_kwargs or {},
        tensorboard,
        observer,
    )
    check_algorithm_keys(params, algo)
    check_features(env_id, obs, params["features"])
    if obs == "rgb":
        try:
            ImageOptions(**params["image"])
        except TypeError:
            fields = ", ".join(f.name for f in dataclasses.fields(ImageOptions))
            raise ValueError(
                f"hyperparameter image must have only {fields}, got {params['image']!r}"
            ) from None
    merged = {**params["env_kwargs"], **dict(env_kwargs or {})}
    checked = check_randomize(
        env_id,
        observer_mode(env_id, feeding),
        merged,
        randomize,
        fixed=env_kwargs,
        fixed_by="--env-option / env_kwargs",
    )
    return env_id, feeding, params, merged, checked


def check_features(env_id: str, obs: str, features: str | None) -> None:
    """ValueError unless ``features`` is None or a feature set of ``env_id``'s system
    (:mod:`observer_gym.train.rl.features`) and ``obs`` reads the state's layout."""
    from observer_gym.envs import system_for_id
    from observer_gym.train.rl.features import feature_names

    if features is None:
        return
    system = system_for_id(env_id)
    allowed = feature_names(system.name)
    if features not in allowed:
        listed = ", ".join(allowed) if allowed else "none (leave features null)"
        raise ValueError(
            f"hyperparameter features={features!r} is no feature set of {system.short_id}; "
            f"allowed: {listed}"
        )
    if obs in ("rgb", "measurements"):
        raise ValueError(
            f"hyperparameter features={features!r} appends to a state-layout observation; "
            f"it needs --obs state or estimate, not {obs}"
        )


def resume_training(
    run_dir: str | Path, timesteps: int | None = None, progress: bool = True
) -> dict[str, Any]:
    """Continue the run in ``run_dir`` from its latest checkpoint up to its configured
    timesteps (or ``timesteps``, a new total); the timestep count carries on from the
    checkpoint's. Returns the final ``state.json``.

    A run that was killed (SIGKILL: :func:`~observer_gym.train.rl.run_dir.read_state`) is
    reported with an :class:`~observer_gym.train.reports.outputs.OutputFolderWarning`, and every
    temp file of the atomic writes in ``run_dir`` is removed (no run is writing there),
    with another. The checkpoint is the newest intact one
    (:func:`~observer_gym.train.rl.run_dir.intact_checkpoint`); each newer one passed over
    (a file missing or damaged) is reported with a :class:`CheckpointWarning`.

    The resumed run holds ``run_dir``'s lock (:mod:`observer_gym.train.reports.folder_lock`)
    from before it checks the folder until it ends, however it ends.

    Raises:
        ValueError: no run or no intact checkpoint there, a config.json changed since the
            run wrote it, a run still writing there, a bad ``timesteps``, or a checkpoint
            that cannot be loaded.
        FolderBusyError: another command holds ``run_dir`` (another ``--resume`` of it, a
            ``train --seeds`` training it); nothing was written.
    """
    run_dir = Path(run_dir)
    read_config(run_dir)  # no run there: said before the lock, which needs the folder
    with folder_lock(run_dir, "train --resume"):
        return _resume(run_dir, timesteps, progress)


def _resume(run_dir: Path, timesteps: int | None, progress: bool) -> dict[str, Any]:
    """:func:`resume_training`'s work, under the folder's lock."""
    state = check_resumable(run_dir)
    config = read_config(run_dir)
    check_recorded_randomize(config)
    checkpoint, problems = intact_checkpoint(run_dir / CHECKPOINTS)
    assert checkpoint is not None  # check_resumable found it
    for problem in problems:
        warnings.warn(
            f"{problem}; resuming from the checkpoint at {checkpoint['timesteps']} steps",
            CheckpointWarning,
            stacklevel=2,
        )
    curve_problem = eval_csv_problem(run_dir / "eval.csv")
    if curve_problem is not None:
        raise ValueError(
            f"{run_dir / 'eval.csv'} is not a training run's evaluation curve ({curve_problem}); "
            "restore it, or remove it to start the curve afresh"
        )
    if state is None and (run_dir / STATE_FILE).exists():
        warnings.warn(
            f"{run_dir / STATE_FILE} is not readable as a run's state; resuming from the "
            f"checkpoint at {checkpoint['timesteps']} steps and writing a new one",
            OutputFolderWarning,
            stacklevel=2,
        )
    if state is not None and state["status"] == "killed":
        warnings.warn(
            f"{killed_text(run_dir, state)}; resuming from its checkpoint at "
            f"{checkpoint['timesteps']} steps",
            OutputFolderWarning,
            stacklevel=2,
        )
    remove_stale_temps(run_dir, all_temps=True)
    if timesteps is not None:
        if int(timesteps) != timesteps or timesteps < 1:
            raise ValueError(f"timesteps must be an integer >= 1, got {timesteps!r}")
        config["hyperparams"]["n_timesteps"] = int(timesteps)
        write_config(run_dir, config)
    return learn(run_dir, config, progress=progress, checkpoint=checkpoint)


def check_recorded_randomize(config: Mapping[str, Any]) -> None:
    """ValueError, before anything is written, if the randomisation a run recorded
    (config.json ``randomize``) could draw a world the env refuses: a run started before
    the whole range was checked (:func:`~observer_gym.train.rl.randomize.check_randomize`)
    would otherwise die at that draw again."""
    if not config.get("randomize"):
        return
    from observer_gym.train.core.checks import observer_mode
    from observer_gym.train.rl.randomize import check_randomize

    env_id, obs = config["env_id"], config["obs"]
    feeding = observer_for(
        env_id,
        obs,
        config["estimate_from"] or "measurements",
        config.get("observer") if obs == "estimate" else None,
    )
    try:
        check_randomize(
            env_id, observer_mode(env_id, feeding), config["env_kwargs"], config["randomize"]
        )
    except ValueError as error:
        raise ValueError(f"the run's recorded {error}; start a new run with another") from None


def continue_run(run_dir: str | Path, timesteps: int | None = None) -> dict[str, Any]:
    """Train the run in ``run_dir`` on, without a progress bar: from its latest checkpoint
    (:func:`resume_training`, ``timesteps`` a new total), or, if it has none yet, from its
    start with its config.json, after removing what an earlier start that saved no
    checkpoint left (``eval.csv``, ``curve.png``, ``state.json``, ``monitor/``,
    ``logs/``), with an :class:`~observer_gym.train.reports.outputs.OutputFolderWarning`. A
    finished run is left as it is. Returns the final ``state.json``; the one function a
    worker process or a Ray task of ``train --seeds`` runs.

    Holds ``run_dir``'s lock while it checks and trains.

    Raises:
        ValueError: no run in ``run_dir``, one still writing there, or a bad ``timesteps``.
        FolderBusyError: another command holds ``run_dir``; nothing was written.
    """
    run_dir = Path(run_dir)
    read_config(run_dir)  # no run there: said before the lock, which needs the folder
    with folder_lock(run_dir, "train --seeds"):
        return _continue(run_dir, timesteps)


def _continue(run_dir: Path, timesteps: int | None) -> dict[str, Any]:
    """:func:`continue_run`'s work, under the folder's lock."""
    config = read_config(run_dir)
    check_recorded_randomize(config)
    state = read_state(run_dir)
    if state is not None and state["status"] == "finished" and timesteps is None:
        return state
    if (run_dir / CHECKPOINTS / LATEST).exists():  # resumed from its newest intact one
        return _resume(run_dir, timesteps, progress=False)
    if state is not None and state["status"] == "running":
        raise ValueError(f"the training run in {run_dir} is still running; stop it first")
    left = [run_dir / name for name in ("eval.csv", "curve.png", STATE_FILE, "monitor", "logs")]
    left = [path for path in left if path.exists()]
    if left:
        warnings.warn(
            f"{run_dir} saved no checkpoint before it stopped; training it from the start "
            f"(removed {', '.join(path.name for path in left)})",
            OutputFolderWarning,
            stacklevel=2,
        )
        for path in left:
            shutil.rmtree(path) if path.is_dir() else path.unlink()
    remove_stale_temps(run_dir, all_temps=True)
    if timesteps is not None:
        config["hyperparams"]["n_timesteps"] = int(timesteps)
        write_config(run_dir, config)
    return learn(run_dir, config, progress=False)


def training_text(run_dir: Path, state: Mapping[str, Any]) -> str:
    """What ``observer-gym train`` prints of a run's final ``state``: how far it got, its
    speed, the output folder and, when interrupted, how to resume."""
    text = (
        f"observer-gym train: {state['status']} at {state['timesteps']} of "
        f"{state['target_timesteps']} steps, {state['train_steps_per_s']:.0f} env steps/s "
        f"while training; output: {run_dir}"
    )
    if state["status"] == "interrupted":
        text += (
            f"\nlast checkpoint: {state['last_checkpoint_timesteps']} steps; continue with "
            f"'observer-gym train --resume {run_dir}'"
        )
    return text
