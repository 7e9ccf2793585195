"""TargetFollower's training data for its learned observer and its learned detector: the
VTC runs the episodes (estimation/target_follower/learned.py and learned_detector.py
describe the data, its ranges and the networks fitted on it)."""

from __future__ import annotations

import tempfile
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np

from observer_gym.controllers import make_controller
from observer_gym.estimation.target_follower import learned_detector
from observer_gym.estimation.target_follower.frames import FrameReader
from observer_gym.estimation.target_follower.learned import (
    EPISODE_STEPS,
    TRAINING_RANGES,
    LearnedEstimator,
)
from observer_gym.estimation.target_follower.learned_detector import ACTION_NOISE
from observer_gym.estimation.target_follower.state_layout import RobotStep
from observer_gym.train.rl.randomize import randomize_of_ranges

if TYPE_CHECKING:  # frame_training imports torch, which importing this module must not
    from observer_gym.estimation.learned.frame_training import FrameDataset

__all__ = ["collect", "collect_frames", "player", "record_episodes"]


# the observer whose env a training recording keeps: the measurements, no filter
OBSERVER = "detections"


def player(act_with: Any = None) -> Any:
    """The training episodes' player (:func:`~observer_gym.train.experiments.record.
    record_played`): the VTC on the true state, or with ``act_with`` (a
    :class:`~observer_gym.estimation.learned.network.GaussianMLP`) on that network's
    estimate (:class:`~observer_gym.estimation.target_follower.learned.LearnedEstimator`),
    plus white noise of std ``ACTION_NOISE`` drawn from the recording's generator, clipped
    to the action space."""

    def policy_for(world: gym.Env, rng: np.random.Generator) -> Any:
        base: Any = world.unwrapped
        controller = make_controller("vtc", world)
        low, high = world.action_space.low, world.action_space.high  # type: ignore[attr-defined]
        frames = FrameReader(base, owner="collect")
        estimator = LearnedEstimator(act_with)
        delta_y_m = base.calibration["delta_y_m"]
        noise_std = np.asarray(ACTION_NOISE)
        last: list[np.ndarray | None] = [None]  # the action before

        def act(obs: Any, info: Any) -> np.ndarray:
            if act_with is None:
                acted_on = np.asarray(info["state"], dtype=float)
            else:
                robot = RobotStep.from_info(info, last[0], delta_y_m)
                acted_on, _, _ = estimator.step(frames.newest(obs, info), robot)
            with warnings.catch_warnings():  # the VTC's first singular stop warns
                warnings.simplefilter("ignore", RuntimeWarning)
                planned, _ = controller.predict(acted_on, deterministic=True)
            action = np.clip(planned + rng.normal(0.0, noise_std), low, high)
            last[0] = action
            return action.astype(np.float32)

        return act

    return policy_for


def record_episodes(
    out_dir: str | Path,
    episodes: int,
    seed: int,
    steps: int = EPISODE_STEPS,
    act_with: Any = None,
) -> dict[str, Any]:
    """Record ``episodes`` training episodes (estimation/target_follower/learned.py's
    docstring) of up to ``steps`` steps into the new folder ``out_dir``: each draws its
    sensor from :data:`TRAINING_RANGES` and then its world's seed, from ``seed``; the
    :func:`player` acts. Returns what its ``record.json`` holds."""
    from observer_gym.train.experiments.record import record_played

    return record_played(
        "TargetFollower-v0",
        OBSERVER,
        out_dir,
        randomize=randomize_of_ranges(TRAINING_RANGES),
        episodes=episodes,
        seed=seed,
        steps=steps,
        player=player(act_with),
        player_name="vtc-on-truth" if act_with is None else "vtc-on-learned",
        config={"action_noise": list(ACTION_NOISE)},
    )


def collect(
    episodes: int,
    seed: int,
    steps: int = EPISODE_STEPS,
    act_with: Any = None,
    out_dir: str | Path | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(features (N, 37), truth (N, 6), episode (N,)) from ``episodes`` training episodes
    of up to ``steps`` steps (estimation/target_follower/learned.py's docstring),
    reproducible from ``seed``: recorded (:func:`record_episodes`) into the new folder
    ``out_dir`` (a temporary one, removed after, if None) and read back
    (:func:`~observer_gym.train.experiments.learned_observers.recorded.training_arrays`):
    the steps where the target is tracked and a frame has shown it. With ``act_with`` (a
    :class:`~observer_gym.estimation.learned.network.GaussianMLP`) the VTC acts on that
    network's estimate instead of the truth: the states the network's own errors lead to
    (the data of a DAgger round)."""
    from observer_gym.train.experiments.learned_observers.recorded import training_arrays

    if out_dir is not None:
        record_episodes(out_dir, episodes, seed, steps, act_with)
        return training_arrays("TargetFollower-v0", out_dir)
    with tempfile.TemporaryDirectory(prefix="target_follower-collect-") as tmp:
        folder = Path(tmp) / "recording"
        record_episodes(folder, episodes, seed, steps, act_with)
        return training_arrays("TargetFollower-v0", folder)


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
