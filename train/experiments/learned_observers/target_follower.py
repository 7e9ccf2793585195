"""TargetFollower's training data for its learned observer and its learned detector: the
VTC runs the episodes (estimation/target_follower/learned.py and learned_detector.py
describe the data, its ranges and the networks fitted on it)."""

from __future__ import annotations

import warnings
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np

from observer_gym.controllers import make_controller
from observer_gym.envs.target_follower import StateIndex
from observer_gym.estimation.target_follower import learned_detector
from observer_gym.estimation.target_follower.frames import FrameReader
from observer_gym.estimation.target_follower.learned import (
    EPISODE_STEPS,
    N_OUT,
    TRAINING_RANGES,
    LearnedEstimator,
)
from observer_gym.estimation.target_follower.learned_detector import ACTION_NOISE
from observer_gym.estimation.target_follower.state_layout import RobotStep
from observer_gym.train.rl.randomize import draw_options, randomize_of_ranges

if TYPE_CHECKING:  # frame_training imports torch, which importing this module must not
    from observer_gym.estimation.learned.frame_training import FrameDataset

__all__ = ["collect", "collect_frames"]


def collect(
    episodes: int, seed: int, steps: int = EPISODE_STEPS, act_with: Any = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(features (N, 37), truth (N, 6), episode (N,)) from ``episodes`` training episodes
    of up to ``steps`` steps (estimation/target_follower/learned.py's docstring),
    reproducible from ``seed``. With ``act_with`` (a
    :class:`~observer_gym.estimation.learned.network.GaussianMLP`) the VTC acts on that
    network's estimate
    (:class:`~observer_gym.estimation.target_follower.learned.LearnedEstimator`) instead of
    the truth: the states the network's own errors lead to (the data of a DAgger round)."""
    rng = np.random.default_rng(seed)
    noise_std = np.asarray(ACTION_NOISE)
    xs, ys, eps = [], [], []
    randomize = randomize_of_ranges(TRAINING_RANGES)
    for episode in range(episodes):
        options = draw_options(randomize, rng)
        env = gym.make("observer_gym/TargetFollower-v0", obs_mode="measurements", **options)
        try:
            base: Any = env.unwrapped
            controller = make_controller("vtc", env)
            low, high = env.action_space.low, env.action_space.high  # type: ignore[attr-defined]
            frames = FrameReader(base, owner="collect")
            estimator = LearnedEstimator(act_with)
            delta_y_m = base.calibration["delta_y_m"]
            obs, info = env.reset(seed=int(rng.integers(2**31)))
            action = None
            for _ in range(steps):
                robot = RobotStep.from_info(info, action, delta_y_m)
                frame = frames.newest(obs, info)
                truth = np.asarray(info["state"], dtype=float)
                if act_with is None:
                    estimator.features.add(frame, robot)
                    acted_on = truth
                else:
                    acted_on, _, _ = estimator.step(frame, robot)
                if truth[StateIndex.TRACKING_VALID] >= 0.5 and estimator.features.any_detected:
                    xs.append(estimator.features.vector(robot.time_s))
                    ys.append(truth[:N_OUT])
                    eps.append(episode)
                with warnings.catch_warnings():  # the VTC's first singular stop warns
                    warnings.simplefilter("ignore", RuntimeWarning)
                    planned, _ = controller.predict(acted_on, deterministic=True)
                action = np.clip(planned + rng.normal(0.0, noise_std), low, high)
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
    ``episodes`` lockstep episodes (estimation/target_follower/learned_detector.py's
    docstring), reproducible from ``seed``."""
    from observer_gym.train.experiments.learned_observers.frame_data import collect_lockstep

    return collect_lockstep(
        "observer_gym/TargetFollower-v0",
        episodes,
        seed,
        steps=steps,
        stride=learned_detector.STRIDE,
        ranges=learned_detector.FRAME_RANGES,
        controller="vtc",
        noise_range=learned_detector.ACTION_NOISE_RANGE,
        labels_of=learned_detector.labels_of,
        net_size_px=learned_detector.NET_SIZE_PX,
        noise_scale=np.asarray(ACTION_NOISE),
    )
