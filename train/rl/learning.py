"""The training loop of a run: its vectorised envs, the stable-baselines3 model (new or
from a checkpoint), the callbacks (checkpoints, the evaluation curve) and ``learn``, as
:mod:`observer_gym.train.rl.training` starts and resumes it.

Seeds: the training envs of a run with seed s reset first with 1,000,000 + 1,000 s + rank
(after a resume, plus the timestep count), and evaluation uses 2,000,000 + 1,000 s.
"""

from __future__ import annotations

import csv
import functools
import io
import shutil
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from observer_gym.envs.json_file import read_bytes_limited
from observer_gym.train.core.signals import signals_deferred, sigterm_as_interrupt
from observer_gym.train.reports.outputs import (
    write_json_atomic,
    write_text_atomic,
    writer_identity,
)
from observer_gym.train.rl.agent_env import make_agent_env
from observer_gym.train.rl.callbacks import EveryStepsCallback
from observer_gym.train.rl.run_dir import (
    CHECKPOINTS,
    CONFIG_FILE,
    FINAL_MODEL,
    FINAL_VECNORMALIZE,
    STATE_FILE,
    latest_checkpoint,
)

if TYPE_CHECKING:
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

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


MAX_EVAL_CSV_BYTES = 64 * 1024 * 1024  # a row is about 60 bytes: a million evaluations


def _csv_line(cells: Sequence[Any]) -> str:
    out = io.StringIO()
    csv.writer(out, lineterminator="\n").writerow(cells)
    return out.getvalue()


def append_eval_row(path: Path, row: Sequence[Any]) -> None:
    """Add ``row`` to the evaluation curve ``path`` (its header first if it is new): the
    whole file is rewritten beside it and renamed into place, so a link there is replaced,
    never written through, and a reader sees the old curve or the new one."""
    old = _csv_line(EVAL_COLUMNS)
    if path.exists():
        old = read_bytes_limited(path, MAX_EVAL_CSV_BYTES).decode("utf-8", errors="replace")
    write_text_atomic(path, old + _csv_line(row))


def eval_csv_problem(path: Path) -> str | None:
    """What is wrong with the evaluation curve ``path`` as a resume would append to it
    (its header is not :data:`EVAL_COLUMNS`, a row is not that many numbers, or it is no
    regular file or too large); None if nothing, or if there is none."""
    if not path.exists() and not path.is_symlink():
        return None
    try:
        text = read_bytes_limited(path, MAX_EVAL_CSV_BYTES).decode("utf-8")
    except (OSError, ValueError) as exc:
        return str(exc)
    rows = list(csv.reader(io.StringIO(text)))
    if not rows or tuple(rows[0]) != EVAL_COLUMNS:
        return f"its header is not {','.join(EVAL_COLUMNS)}"
    for number, cells in enumerate(rows[1:], start=2):
        try:
            if len(cells) != len(EVAL_COLUMNS) or not all(np.isfinite(float(c)) for c in cells):
                raise ValueError
        except ValueError:
            return f"line {number} is not {len(EVAL_COLUMNS)} finite numbers"
    return None


def replace_links(run_dir: Path) -> list[Path]:
    """Remove the symbolic links where a training run writes through a path it reuses
    (``monitor/`` and its files, ``logs/``), so that training writes new files in the
    run's folder and never into a link's target; the links removed (their targets are
    left as they were). ``eval.csv`` and the files written by rename need none: a rename
    replaces a link."""
    removed = []
    for name in ("monitor", "logs"):
        folder = run_dir / name
        if folder.is_symlink():
            folder.unlink()
            removed.append(folder)
        elif folder.is_dir():
            for path in folder.rglob("*"):
                if path.is_symlink():
                    path.unlink()
                    removed.append(path)
    return removed


def _vec_env(
    config: Mapping[str, Any],
    n_envs: int,
    seed: int,
    monitor_dir: Path | None,
    randomize: bool = False,
):
    """The training (or evaluation, ``monitor_dir`` None and one env) vector env; with
    ``randomize``, drawing the run's randomised options (config ``randomize``) anew at
    every reset (:class:`~observer_gym.train.rl.randomize.RandomizedEnv`)."""
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
        (config.get("randomize") or None) if randomize else None,
        config["hyperparams"].get("measurement_stack", 1),  # absent before it existed
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


def _discard_new_run(run_dir: Path) -> None:
    """Remove what a new run wrote before its algorithm refused it (config.json and
    monitor/; the run holds its folder's lock), so the folder takes a new run."""
    (run_dir / CONFIG_FILE).unlink(missing_ok=True)
    shutil.rmtree(run_dir / "monitor", ignore_errors=True)


def _refused(name: str, run_dir: Path, exc: Exception) -> ValueError:
    reason = " ".join(str(exc).split()) or type(exc).__name__
    return ValueError(
        f"{name} refuses the hyperparameters: {reason}; nothing was trained or kept in {run_dir}"
    )


def learn(
    run_dir: Path,
    config: dict[str, Any],
    progress: bool,
    checkpoint: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Train the run in ``run_dir`` (from ``checkpoint``, as
    :func:`~observer_gym.train.rl.run_dir.intact_checkpoint` gives it, when resuming)."""
    import torch
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.utils import set_random_seed
    from stable_baselines3.common.vec_env import VecNormalize

    from observer_gym.train.core.plots import plot_learning_curve
    from observer_gym.train.rl.checkpoints import (
        CheckpointCallback,
        replace_atomically,
        save_checkpoint,
    )
    from observer_gym.train.rl.hyperparams import algorithm_class, build_algo_kwargs, split
    from observer_gym.train.rl.normalizer_file import (
        build_vec_normalize,
        read_stats,
        record_final_files,
        save_normalizer,
    )

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
    # training draws the randomised options (if any); the evaluation curve scores the
    # agent on the run's fixed options, as evaluate, run, compare and benchmark load it
    replace_links(run_dir)  # a link in the folder is replaced, never written through
    venv = _vec_env(config, training["n_envs"], train_seed, run_dir / "monitor", randomize=True)
    eval_env = _vec_env(config, 1, eval_seed, None)
    try:
        normalize = training["normalize"]
        if normalize:
            options = {"gamma": algo_kwargs.get("gamma", 0.99), **normalize}
            if checkpoint:
                stats = read_stats(checkpoint["vecnormalize"])  # plain arrays, no pickle
                try:
                    venv = build_vec_normalize(stats, venv, training=True)
                except ValueError as exc:  # statistics of another observation
                    raise _unloadable(run_dir, start_steps, exc) from exc
            else:
                venv = VecNormalize(venv, **options)
            eval_env = VecNormalize(
                eval_env, training=False, norm_obs=options.get("norm_obs", True), norm_reward=False
            )
        if checkpoint:
            try:
                model = cls.load(checkpoint["model"], env=venv, device="cpu")
                if "replay_buffer" in checkpoint:
                    # saved for off-policy algorithms only (save_checkpoint)
                    cast("OffPolicyAlgorithm", model).load_replay_buffer(
                        checkpoint["replay_buffer"]
                    )
            except Exception as exc:  # files SB3 cannot load (another version, no hashes)
                raise _unloadable(run_dir, start_steps, exc) from exc
        else:
            policy = training["policy"] or default_policy(venv.observation_space)
            kwargs = build_algo_kwargs(algo_kwargs, int(np.prod(venv.action_space.shape)))
            try:
                model = cls(policy, venv, seed=seed, device="cpu", verbose=0, **kwargs)
            # past the up-front checks; RuntimeError: PyTorch refusing a layer's size
            except (AssertionError, ValueError, TypeError, RuntimeError) as exc:
                _discard_new_run(run_dir)
                raise _refused(cls.__name__, run_dir, exc) from exc
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
        callbacks: list[BaseCallback] = [
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
                    save_normalizer(venv, run_dir / FINAL_VECNORMALIZE)
                replace_atomically(run_dir / FINAL_MODEL, model.save)
                record_final_files(run_dir)  # final.json: their sha256, checked on load
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
        append_eval_row(self.csv_path, row)
        self.logger.record("eval/return_mean", row[2])
        self.time_s += time.perf_counter() - tic_s
