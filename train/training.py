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
- when finished, ``model.zip`` and ``vecnormalize.pkl``; ``state.json`` says the status
  (running, interrupted, finished), the timestep count, the throughput and the
  ``writer`` (PID, host, process start time). A run killed with SIGKILL stays "running"
  there; readers report it as "killed" once its writer is gone
  (:func:`observer_gym.train.run_dir.read_state`), and ``--resume`` then removes the temp
  files it left and says so (an :class:`~observer_gym.train.outputs.OutputFolderWarning`).

Seeds: the training envs of a run with seed s reset first with 1,000,000 + 1,000 s + rank
(after a resume, plus the timestep count), and evaluation uses 2,000,000 + 1,000 s, so
the episodes that ``observer-gym run`` and ``evaluate`` score (seeds 0, 1, ...) are never
trained on. On CPU, two runs with the same seed and settings give identical models.
"""

from __future__ import annotations

import csv
import dataclasses
import functools
import shutil
import time
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from observer_gym.train.agent_env import ImageOptions, make_agent_env, observer_for
from observer_gym.train.callbacks import EveryStepsCallback
from observer_gym.train.outputs import (
    OneLineWarning,
    OutputFolderWarning,
    output_folder,
    package_versions,
    remove_stale_temps,
    to_jsonable,
    write_json_atomic,
    writer_identity,
)
from observer_gym.train.run_dir import (
    CHECKPOINTS,
    FINAL_MODEL,
    FINAL_VECNORMALIZE,
    LATEST,
    STATE_FILE,
    check_resumable,
    intact_checkpoint,
    killed_text,
    latest_checkpoint,
    read_config,
    read_state,
    write_config,
)
from observer_gym.train.signals import signals_deferred, sigterm_as_interrupt


class CheckpointWarning(OneLineWarning):
    """A checkpoint passed over when resuming (a file missing or damaged)."""


TRAIN_SEED_OFFSET = 1_000_000
EVAL_SEED_OFFSET = 2_000_000
SEED_STRIDE = 1_000
EVAL_COLUMNS = (
    "timesteps",
    "wall_time_s",
    "return_mean",
    "return_std",
    "length_mean",
    "episodes",
)


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
    tensorboard: bool = False,
    progress: bool = True,
    cli_args: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Train ``algo`` on ``env_id`` reading ``obs``; returns the final ``state.json``.

    Args:
        env_id: a registered id, with or without ``observer_gym/``.
        algo: ppo, sac or td3.
        obs: state, estimate or rgb (see :mod:`observer_gym.train.agent_env`).
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
        tensorboard: also write TensorBoard logs (needs the tensorboard package).
        progress: show SB3's progress bar.
        cli_args: the command line, recorded in config.json.

    Raises:
        ValueError: any bad argument or hyperparameter, before anything is written.
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
        tensorboard=tensorboard,
        cli_args=cli_args,
    )
    out_dir = Path(out_dir)
    write_run_config(out_dir, config)
    return _learn(out_dir, config, progress=progress)


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
    tensorboard: bool = False,
    cli_args: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The ``config.json`` of a new run (the arguments of :func:`train_agent`), after
    its checks (:func:`check_training`) and a probe env that gives the action bounds;
    nothing is written.

    Raises:
        ValueError: any bad argument or hyperparameter.
    """
    env_id, feeding, params, env_kwargs = check_training(
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
        tensorboard=tensorboard,
    )
    probe = make_agent_env(
        env_id, obs, estimate_from, env_kwargs, params["image"], observer, params["features"]
    )
    try:  # the action bounds a loaded agent maps back to, and a check that the env builds
        action_space = probe.unwrapped.action_space
    finally:
        probe.close()
    encoder = params["image"].get("encoder") if obs == "rgb" else None
    recorded = {}  # the frame encoder's file, which a loaded agent checks
    if encoder is not None:
        from observer_gym.train.pixel_encoder import encoder_sha256  # deferred: PyTorch

        recorded["encoder_sha256"] = encoder_sha256(encoder)
    return to_jsonable(
        {
            "env_id": env_id,
            "algo": algo,
            "obs": obs,
            "estimate_from": estimate_from if obs == "estimate" else None,
            "observer": feeding,
            "env_kwargs": env_kwargs,
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
    config.json, atomically, with its sha256 (:func:`~observer_gym.train.run_dir.
    write_config`)."""
    with output_folder(run_dir, "train", marker=False):
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
    tensorboard: bool = False,
) -> tuple[str, str, dict[str, Any], dict[str, Any]]:
    """The checks of :func:`train_agent` (same arguments), which build no env and write
    nothing: the env, ``obs`` and ``estimate_from``, the seed, the env options, the
    output folder and TensorBoard (:func:`observer_gym.train.checks.check_training_request`),
    then the hyperparameters' keys against the algorithm's constructor (this imports
    stable-baselines3) and, for ``obs="rgb"``, the image options.

    Returns:
        The registered env id, the observer that feeds the agent, the resolved
        hyperparameters and the env's ``gym.make`` options (the YAML's with
        ``env_kwargs`` over them).

    Raises:
        ValueError: naming the bad argument or hyperparameter and what is allowed.
    """
    from observer_gym.train.checks import check_training_request, training_overrides
    from observer_gym.train.hyperparams import check_algorithm_keys
    from observer_gym.train.systems import resolve_env_id

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
    return env_id, feeding, params, {**params["env_kwargs"], **dict(env_kwargs or {})}


def check_features(env_id: str, obs: str, features: str | None) -> None:
    """ValueError unless ``features`` is None or a feature set of ``env_id``'s system
    (:mod:`observer_gym.train.features`) and ``obs`` reads the state's layout."""
    from observer_gym.envs import system_for_id
    from observer_gym.train.features import feature_names

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
    if obs == "rgb":
        raise ValueError(
            f"hyperparameter features={features!r} appends to a state-layout observation; "
            "it needs --obs state or estimate, not rgb"
        )


def resume_training(
    run_dir: str | Path, timesteps: int | None = None, progress: bool = True
) -> dict[str, Any]:
    """Continue the run in ``run_dir`` from its latest checkpoint up to its configured
    timesteps (or ``timesteps``, a new total); the timestep count carries on from the
    checkpoint's. Returns the final ``state.json``.

    A run that was killed (SIGKILL: :func:`~observer_gym.train.run_dir.read_state`) is
    reported with an :class:`~observer_gym.train.outputs.OutputFolderWarning`, and every
    temp file of the atomic writes in ``run_dir`` is removed (no run is writing there),
    with another. The checkpoint is the newest intact one
    (:func:`~observer_gym.train.run_dir.intact_checkpoint`); each newer one passed over
    (a file missing or damaged) is reported with a :class:`CheckpointWarning`.

    Raises:
        ValueError: no run or no intact checkpoint there, a config.json changed since the
            run wrote it, a run still writing there, a bad ``timesteps``, or a checkpoint
            that cannot be loaded.
    """
    run_dir = Path(run_dir)
    state = check_resumable(run_dir)
    config = read_config(run_dir)
    checkpoint, problems = intact_checkpoint(run_dir / CHECKPOINTS)
    for problem in problems:
        warnings.warn(
            f"{problem}; resuming from the checkpoint at {checkpoint['timesteps']} steps",
            CheckpointWarning,
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
    return _learn(run_dir, config, progress=progress, checkpoint=checkpoint)


def continue_run(run_dir: str | Path, timesteps: int | None = None) -> dict[str, Any]:
    """Train the run in ``run_dir`` on, without a progress bar: from its latest checkpoint
    (:func:`resume_training`, ``timesteps`` a new total), or, if it has none yet, from its
    start with its config.json, after removing what an earlier start that saved no
    checkpoint left (``eval.csv``, ``curve.png``, ``state.json``, ``monitor/``,
    ``logs/``), with an :class:`~observer_gym.train.outputs.OutputFolderWarning`. A
    finished run is left as it is. Returns the final ``state.json``; the one function a
    worker process or a Ray task of ``train --seeds`` runs.

    Raises:
        ValueError: no run in ``run_dir``, one still writing there, or a bad ``timesteps``.
    """
    run_dir = Path(run_dir)
    config = read_config(run_dir)
    state = read_state(run_dir)
    if state is not None and state["status"] == "finished" and timesteps is None:
        return state
    if (run_dir / CHECKPOINTS / LATEST).exists():  # resumed from its newest intact one
        return resume_training(run_dir, timesteps, progress=False)
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
    return _learn(run_dir, config, progress=False)


def _vec_env(config: Mapping[str, Any], n_envs: int, seed: int, monitor_dir: Path | None):
    """The training (or evaluation, ``monitor_dir`` None and one env) vector env."""
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    env_fn = functools.partial(
        make_agent_env,
        config["env_id"],
        config["obs"],
        config["estimate_from"] or "measurements",
        config["env_kwargs"],
        config["hyperparams"]["image"],
        # the observer by name for an estimate (runs written before config.json recorded
        # it as chosen are the estimate_from default, which is what observer_for gives)
        config.get("observer") if config["obs"] == "estimate" else None,
        config["hyperparams"].get("features"),  # absent from runs written before it existed
    )
    subproc = config["hyperparams"]["vec_env"] == "subproc" and n_envs > 1
    return make_vec_env(
        env_fn,
        n_envs=n_envs,
        seed=seed,
        monitor_dir=None if monitor_dir is None else str(monitor_dir),
        vec_env_cls=SubprocVecEnv if subproc else DummyVecEnv,
        vec_env_kwargs={"start_method": "spawn"} if subproc else None,
    )


def _unloadable(run_dir: Path, steps: int, exc: Exception) -> ValueError:
    return ValueError(
        f"the checkpoint at {steps} steps in {run_dir / CHECKPOINTS} cannot be loaded: "
        f"{type(exc).__name__}: {' '.join(str(exc).split())}"
    )


def _learn(
    run_dir: Path,
    config: dict[str, Any],
    progress: bool,
    checkpoint: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Train the run in ``run_dir`` (from ``checkpoint``, as
    :func:`~observer_gym.train.run_dir.intact_checkpoint` gives it, when resuming)."""
    import torch
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.utils import set_random_seed
    from stable_baselines3.common.vec_env import VecNormalize

    from observer_gym.train.checkpoints import (
        CheckpointCallback,
        replace_atomically,
        save_checkpoint,
    )
    from observer_gym.train.hyperparams import algorithm_class, build_algo_kwargs, split
    from observer_gym.train.plots import plot_learning_curve

    training, algo_kwargs = split(config["hyperparams"])
    cls = algorithm_class(config["algo"])
    seed = config["seed"]
    torch.set_num_threads(training["torch_threads"])
    resume = checkpoint is not None
    start_steps = int(checkpoint["timesteps"]) if checkpoint else 0
    set_random_seed(seed + start_steps)
    total = training["n_timesteps"]
    save_replay_buffer = config["obs"] != "rgb"  # image buffers are GBs; not kept

    train_seed = TRAIN_SEED_OFFSET + SEED_STRIDE * seed + start_steps
    eval_seed = EVAL_SEED_OFFSET + SEED_STRIDE * seed
    venv = _vec_env(config, training["n_envs"], train_seed, run_dir / "monitor")
    eval_env = _vec_env(config, 1, eval_seed, None)
    try:
        normalize = training["normalize"]
        if normalize:
            options = {"gamma": algo_kwargs.get("gamma", 0.99), **normalize}
            if checkpoint:
                try:
                    venv = VecNormalize.load(str(checkpoint["vecnormalize"]), venv)
                except Exception as exc:  # a damaged set saved before hashes were recorded
                    raise _unloadable(run_dir, start_steps, exc) from exc
                venv.training = True
            else:
                venv = VecNormalize(venv, **options)
            eval_env = VecNormalize(
                eval_env, training=False, norm_obs=options.get("norm_obs", True), norm_reward=False
            )
        if checkpoint:
            try:
                model = cls.load(checkpoint["model"], env=venv, device="cpu")
                if "replay_buffer" in checkpoint:
                    model.load_replay_buffer(checkpoint["replay_buffer"])
            except Exception as exc:  # files SB3 cannot load (another version, no hashes)
                raise _unloadable(run_dir, start_steps, exc) from exc
        else:
            policy = training["policy"] or default_policy(venv.observation_space)
            kwargs = build_algo_kwargs(algo_kwargs, int(np.prod(venv.action_space.shape)))
            model = cls(policy, venv, seed=seed, device="cpu", verbose=0, **kwargs)
        segment = f"resume-{start_steps}" if resume else "start"
        formats = ["csv"] + (["tensorboard"] if config["tensorboard"] else [])
        model.set_logger(configure(str(run_dir / "logs" / segment), formats))

        evaluation = EvalCurveCallback(
            eval_env,
            run_dir / "eval.csv",
            every_steps=training["eval_freq"],
            episodes=training["eval_episodes"],
            eval_seed=eval_seed,
        )
        callbacks = [
            CheckpointCallback(
                run_dir / "checkpoints", training["checkpoint_freq"], save_replay_buffer
            ),
            evaluation,
        ]
        writer = writer_identity()  # tells a killed run from a running one (read_state)
        state = {
            "status": "running",
            "timesteps": start_steps,
            "target_timesteps": total,
            "writer": writer,
        }
        write_json_atomic(run_dir / STATE_FILE, state)
        tic_s = time.perf_counter()
        status = "finished"
        try:
            with sigterm_as_interrupt():
                model.learn(
                    total_timesteps=max(total - start_steps, 0),
                    callback=callbacks,
                    reset_num_timesteps=not resume,
                    progress_bar=progress,
                )
        except KeyboardInterrupt:
            status = "interrupted"
        wall_time_s = time.perf_counter() - tic_s
        steps = int(model.num_timesteps) - start_steps
        train_time_s = max(wall_time_s - evaluation.time_s, 1e-9)
        with signals_deferred():  # the run's end is written whole, then a signal counts
            if status == "finished":
                save_checkpoint(model, run_dir / "checkpoints", save_replay_buffer)
                if normalize:
                    replace_atomically(run_dir / FINAL_VECNORMALIZE, venv.save)
                replace_atomically(run_dir / FINAL_MODEL, model.save)
            latest = latest_checkpoint(run_dir / "checkpoints")
            state = {
                "status": status,
                "timesteps": int(model.num_timesteps),
                "target_timesteps": total,
                "last_checkpoint_timesteps": None if latest is None else latest["timesteps"],
                "segment_steps": steps,
                "segment_wall_time_s": wall_time_s,
                "segment_eval_time_s": evaluation.time_s,
                "train_steps_per_s": steps / train_time_s,
                "writer": writer,
            }
            write_json_atomic(run_dir / STATE_FILE, state)
        if (run_dir / "eval.csv").exists():
            plot_learning_curve(run_dir / "eval.csv", run_dir / "curve.png", config)
        return state
    finally:
        for env in (venv, eval_env):
            try:
                env.close()
            except (BrokenPipeError, ConnectionResetError, EOFError):
                pass  # Ctrl-C reached the SubprocVecEnv workers too; they are gone


def default_policy(space: Any) -> str:
    """SB3's policy for an observation ``space``: MultiInputPolicy for a Dict, CnnPolicy
    for an image, else MlpPolicy."""
    from gymnasium import spaces
    from stable_baselines3.common.preprocessing import is_image_space

    if isinstance(space, spaces.Dict):
        return "MultiInputPolicy"
    return "CnnPolicy" if is_image_space(space) else "MlpPolicy"


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


class EvalCurveCallback(EveryStepsCallback):
    """Every ``every_steps`` env steps, scores the deterministic policy on the same
    ``episodes`` evaluation episodes (seeded with ``eval_seed``) and appends a row of
    :data:`EVAL_COLUMNS` to ``csv_path``; ``time_s`` is the time spent evaluating."""

    def __init__(
        self, eval_env: Any, csv_path: Path, every_steps: int, episodes: int, eval_seed: int
    ) -> None:
        super().__init__(every_steps)
        self.eval_env, self.csv_path = eval_env, Path(csv_path)
        self.episodes, self.eval_seed = episodes, eval_seed
        self.time_s = 0.0
        self._start_s = time.time()

    def _on_training_end(self) -> None:
        if self.num_timesteps % self.every_steps:
            self.act()  # the final policy's score, unless just measured

    def act(self) -> None:
        from stable_baselines3.common.evaluation import evaluate_policy
        from stable_baselines3.common.vec_env import sync_envs_normalization

        tic_s = time.perf_counter()
        if self.model.get_vec_normalize_env() is not None:
            sync_envs_normalization(self.training_env, self.eval_env)
        self.eval_env.seed(self.eval_seed)
        returns, lengths = evaluate_policy(
            self.model,
            self.eval_env,
            n_eval_episodes=self.episodes,
            deterministic=True,
            return_episode_rewards=True,
            warn=False,
        )
        row = [
            self.num_timesteps,
            round(time.time() - self._start_s, 3),
            float(np.mean(returns)),
            float(np.std(returns)),
            float(np.mean(lengths)),
            self.episodes,
        ]
        new = not self.csv_path.exists()
        with open(self.csv_path, "a", newline="") as f:
            writer = csv.writer(f)
            if new:
                writer.writerow(EVAL_COLUMNS)
            writer.writerow(row)
        self.logger.record("eval/return_mean", row[2])
        self.time_s += time.perf_counter() - tic_s
