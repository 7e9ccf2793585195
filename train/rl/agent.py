"""A trained agent as a controller: ``Agent.load(DIR)`` for the folder of
``observer-gym train``; wherever a controller name is taken, ``ALGO:DIR`` names one.

An :class:`Agent` keeps the controller protocol (``reset()`` and SB3's ``predict``), so
``observer-gym run``, ``evaluate`` and ``compare`` drive it exactly as the LQR. It
normalises observations with the run's saved VecNormalize statistics (plain arrays,
:mod:`observer_gym.train.rl.normalizer_file`: nothing of them is unpickled), and maps its
[-1, 1] actions back to the env's units; ``wrap_env`` adds the image preprocessing an
rgb agent was trained with. The run folder itself (config.json, model files, ``ALGO:DIR``)
is read by :mod:`observer_gym.train.rl.run_dir`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from observer_gym.train.rl.agent_env import ImageOptions, to_env_action, wrap_images
from observer_gym.train.rl.features import wrap_features
from observer_gym.train.rl.measurement_input import wrap_measurements
from observer_gym.train.rl.normalizer_file import normalizer_for_spaces, read_stats
from observer_gym.train.rl.run_dir import model_files, read_config


class Agent:
    """A trained SB3 agent with the controller protocol.

    Attributes:
        name: ``ALGO:DIR``.
        algo, obs, run_dir, timesteps: what it is, what it reads, where it is, and how
            many env steps it was trained for (recorded by ``observer-gym run``).
        config: the run's resolved config.json.
    """

    def __init__(
        self,
        model: Any,
        obs_normalizer: Any,
        config: dict[str, Any],
        run_dir: Path,
        steps: int | None,
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
        checkpoint), on the CPU.

        The model and statistics are checked against the sha256 the run recorded, and the
        statistics are read as plain arrays, before the model is loaded
        (:func:`~observer_gym.train.rl.run_dir.model_files`). The model is a
        stable-baselines3 zip, which SB3 partly unpickles: load only folders from a
        trusted source.

        Raises:
            ValueError: no run there, files changed since the run saved them, or
                statistics pickled by an earlier version (naming how to convert them).
        """
        from observer_gym.train.rl.hyperparams import algorithm_class

        config = read_config(run_dir, algo)
        _check_encoder(config, run_dir)
        model_path, stats_path, steps = model_files(run_dir)
        stats = None if stats_path is None else read_stats(stats_path)
        model = algorithm_class(config["algo"]).load(model_path, device="cpu")
        obs_normalizer = None
        if stats is not None:  # SB3's VecNormalize, rebuilt from the arrays
            obs_normalizer = normalizer_for_spaces(
                stats, model.observation_space, model.action_space
            )
        return cls(model, obs_normalizer, config, Path(run_dir), steps)

    def wrap_env(self, env: gym.Env) -> gym.Env:
        """``env`` as the agent saw it in training: camera frames preprocessed for an rgb
        agent, the detections as one vector (stacked) for a measurements agent, through
        its feature set (hyperparameter ``features``); actions are mapped back by
        :meth:`predict`."""
        hyperparams = self.config["hyperparams"]
        if self.obs == "rgb":
            env = wrap_images(env, ImageOptions(**hyperparams["image"]))
        elif self.obs == "measurements":
            env = wrap_measurements(env, hyperparams.get("measurement_stack", 1))
        return wrap_features(env, hyperparams.get("features"))

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


def _check_encoder(config: dict[str, Any], run_dir: str | Path) -> None:
    """ValueError if the frame encoder an rgb agent trained with (its sha256 in
    config.json) is not the file its name points to now."""
    recorded = config.get("encoder_sha256")
    if recorded is None:
        return
    from observer_gym.train.rl.pixel_encoder import encoder_sha256

    name = config["hyperparams"]["image"]["encoder"]
    if encoder_sha256(name) != recorded:
        raise ValueError(
            f"the agent in {run_dir} was trained with another image encoder {name!r} "
            f"(sha256 {recorded[:12]}...); the file it names now has changed"
        )
