"""BallTable's training data for its learned observer and its learned detector: the LQR
runs the episodes (estimation/ball_table/learned.py and learned_detector.py describe the
data, its ranges and the networks fitted on it)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from observer_gym.controllers import make_controller
from observer_gym.estimation.ball_table import learned_detector
from observer_gym.estimation.ball_table.learned import (
    ACTION_NOISE_RAD,
    EPISODE_STEPS,
    TRAINING_RANGES,
    LearnedFeatures,
)

if TYPE_CHECKING:  # frame_training imports torch, which importing this module must not
    from observer_gym.estimation.learned.frame_training import FrameDataset

__all__ = ["collect", "collect_frames"]


def collect(
    episodes: int, seed: int, steps: int = EPISODE_STEPS, act_with: Any = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(features (N, 58), truth (N, 8), episode (N,)) from ``episodes`` training episodes
    of up to ``steps`` steps (estimation/ball_table/learned.py's docstring), reproducible
    from ``seed``. With ``act_with`` (a
    :class:`~observer_gym.estimation.learned.network.GaussianMLP`) the LQR acts on that
    network's estimate instead of the truth: the states the network's own errors lead to
    (the data of a DAgger round)."""
    rng = np.random.default_rng(seed)
    xs, ys, eps = [], [], []
    for episode in range(episodes):
        options: dict[str, Any] = {
            key: float(rng.uniform(*bounds)) for key, bounds in TRAINING_RANGES.items()
        }
        env = gym.make("observer_gym/BallTable-v0", obs_mode="measurements", **options)
        try:
            controller = make_controller("lqr", env)
            box = env.action_space
            if not isinstance(box, spaces.Box):
                raise ValueError(f"BallTable's action space is a Box, got {box}")
            features = LearnedFeatures()
            obs, info = env.reset(seed=int(rng.integers(2**31)))
            action = None
            for _ in range(steps):
                capture_s = features.newest_capture_s(info)
                if capture_s is not None:
                    features.new_frame(obs, capture_s)
                xs.append(features.vector(float(info["time_s"]), action))
                ys.append(np.asarray(info["state"], dtype=float))
                eps.append(episode)
                if act_with is None:
                    acted_on = info["state"]
                else:
                    acted_on, _ = act_with.predict(xs[-1])
                planned, _ = controller.predict(acted_on, deterministic=True)
                noise = rng.normal(0.0, ACTION_NOISE_RAD, 2)
                action = np.clip(planned + noise, box.low, box.high)
                obs, _, terminated, truncated, info = env.step(action.astype(np.float32))
                if terminated or truncated:
                    break
        finally:
            env.close()
    return np.array(xs), np.array(ys), np.array(eps)


def collect_frames(
    episodes: int, seed: int, steps: int = learned_detector.EPISODE_STEPS
) -> FrameDataset:
    """A :class:`~observer_gym.estimation.learned.frame_training.FrameDataset` of
    ``episodes`` lockstep episodes (estimation/ball_table/learned_detector.py's
    docstring), reproducible from ``seed``."""
    from observer_gym.train.experiments.learned_observers.frame_data import collect_lockstep

    return collect_lockstep(
        "observer_gym/BallTable-v0",
        episodes,
        seed,
        steps=steps,
        stride=learned_detector.STRIDE,
        ranges=learned_detector.FRAME_RANGES,
        controller="lqr",
        noise_range=learned_detector.ACTION_NOISE_RANGE_RAD,
        labels_of=learned_detector.labels_of,
        net_size_px=learned_detector.NET_SIZE_PX,
    )
