"""A trained agent as a controller: ``Agent.load(DIR)`` for the folder of
``observer-gym train``; wherever a controller name is taken, ``ALGO:DIR`` names one.

An :class:`Agent` keeps the controller protocol (``reset()`` and SB3's ``predict``), so
``observer-gym run``, ``evaluate`` and ``compare`` drive it exactly as the LQR. It
normalises observations with the run's saved VecNormalize statistics, and maps its
[-1, 1] actions back to the env's units; ``wrap_env`` adds the image preprocessing an
rgb agent was trained with.
"""

from __future__ import annotations

import json
import pickle
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from observer_gym.train.agent_env import ImageOptions, to_env_action, wrap_images
from observer_gym.train.hyperparams import ALGOS

CONFIG_FILE = "config.json"
FINAL_MODEL = "model.zip"
FINAL_VECNORMALIZE = "vecnormalize.pkl"


def parse_agent_spec(name: str) -> tuple[str, Path] | None:
    """``("ppo", Path("runs/x"))`` for ``"ppo:runs/x"``; None for a name without ``ALGO:``
    (a baseline controller's name)."""
    algo, sep, run_dir = name.partition(":")
    if not sep or algo not in ALGOS:
        return None
    if not run_dir:
        raise ValueError(f"agent {name!r} names no folder; expected {algo}:DIR")
    return algo, Path(run_dir)


def read_config(run_dir: str | Path, algo: str | None = None) -> dict[str, Any]:
    """The resolved config.json of the training run in ``run_dir``.

    Raises:
        ValueError: no training run there, or one trained with another algorithm.
    """
    path = Path(run_dir) / CONFIG_FILE
    if not path.is_file():
        raise ValueError(
            f"{run_dir} is not an observer-gym training run (no {CONFIG_FILE}); "
            "make one with 'observer-gym train'"
        )
    config = json.loads(path.read_text())
    if algo is not None and config["algo"] != algo:
        raise ValueError(f"{run_dir} holds a {config['algo']} agent, not {algo}")
    return config


def model_files(run_dir: str | Path) -> tuple[Path, Path | None, int | None]:
    """(model, VecNormalize statistics or None, timesteps or None): the final model of a
    finished run, else its latest checkpoint. ValueError if there is neither."""
    from observer_gym.train.checkpoints import latest_checkpoint

    run_dir = Path(run_dir)
    checkpoint = latest_checkpoint(run_dir / "checkpoints")
    if (run_dir / FINAL_MODEL).is_file():  # written last, after the final checkpoint
        stats = run_dir / FINAL_VECNORMALIZE
        steps = None if checkpoint is None else checkpoint["timesteps"]
        return run_dir / FINAL_MODEL, stats if stats.is_file() else None, steps
    if checkpoint is None:
        raise ValueError(f"{run_dir} has neither {FINAL_MODEL} nor a checkpoint yet")
    return checkpoint["model"], checkpoint.get("vecnormalize"), checkpoint["timesteps"]


class Agent:
    """A trained SB3 agent with the controller protocol.

    Attributes:
        name: ``ALGO:DIR``.
        algo, obs, run_dir, timesteps: what it is, what it reads, where it is, and how
            many env steps it was trained for (recorded by ``observer-gym run``).
        config: the run's resolved config.json.
    """

    def __init__(
        self, model: Any, obs_normalizer: Any, config: dict[str, Any], run_dir: Path, steps: int
    ) -> None:
        self.model, self.obs_normalizer, self.config = model, obs_normalizer, config
        self.algo, self.obs = config["algo"], config["obs"]
        self.run_dir, self.timesteps = str(run_dir), steps
        self.name = f"{self.algo}:{run_dir}"
        self._low = np.asarray(config["action_low"], dtype=np.float64)
        self._high = np.asarray(config["action_high"], dtype=np.float64)

    @classmethod
    def load(cls, run_dir: str | Path, algo: str | None = None) -> Agent:
        """The agent of the training run in ``run_dir`` (final model, else the latest
        checkpoint), on the CPU."""
        from observer_gym.train.hyperparams import algorithm_class

        config = read_config(run_dir, algo)
        model_path, stats_path, steps = model_files(run_dir)
        model = algorithm_class(config["algo"]).load(model_path, device="cpu")
        obs_normalizer = None
        if stats_path is not None:
            with open(stats_path, "rb") as f:
                obs_normalizer = pickle.load(f)  # SB3's VecNormalize, saved by the run
            obs_normalizer.training = False
        return cls(model, obs_normalizer, config, Path(run_dir), steps)

    def wrap_env(self, env: gym.Env) -> gym.Env:
        """``env`` as the agent saw it in training: camera frames preprocessed for an rgb
        agent; unchanged otherwise (actions are mapped back by :meth:`predict`)."""
        if self.obs == "rgb":
            return wrap_images(env, ImageOptions(**self.config["hyperparams"]["image"]))
        return env

    def reset(self) -> None:
        """Nothing to reset: the policies are feed-forward (frame stacks live in the env)."""

    def predict(
        self,
        observation: Any,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        """The action (the env's units) for ``observation``, as SB3's ``predict``."""
        if self.obs_normalizer is not None and self.obs_normalizer.norm_obs:
            observation = self.obs_normalizer.normalize_obs(observation)
        action, _ = self.model.predict(observation, deterministic=deterministic)
        return to_env_action(action, self._low, self._high), state
