"""BallTable's training data for its learned observer and its learned detector: the LQR
runs the episodes (estimation/ball_table/learned.py and learned_detector.py describe the
data, its ranges and the networks fitted on it)."""

from __future__ import annotations

import tempfile
from pathlib import Path
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

__all__ = ["collect", "collect_frames", "player", "record_episodes"]


# the observer whose env a training recording keeps: the measurements, no filter
OBSERVER = "detections"


def player(act_with: Any = None) -> Any:
    """The training episodes' player (:func:`~observer_gym.train.experiments.record.
    record_played`): the LQR on the true state, or with ``act_with`` (a
    :class:`~observer_gym.estimation.learned.network.GaussianMLP`) on that network's
    estimate from the features so far, plus white noise of std :data:`ACTION_NOISE_RAD`
    drawn from the recording's generator, clipped to the action space."""

    def policy_for(world: gym.Env, rng: np.random.Generator) -> Any:
        controller = make_controller("lqr", world)
        box = world.action_space
        if not isinstance(box, spaces.Box):
            raise ValueError(f"BallTable's action space is a Box, got {box}")
        features = LearnedFeatures()
        last: list[np.ndarray | None] = [None]  # the action before, as planned (float64)

        def act(obs: Any, info: Any) -> np.ndarray:
            if act_with is None:
                acted_on = info["state"]
            else:
                capture_s = features.newest_capture_s(info)
                if capture_s is not None:
                    features.new_frame(obs, capture_s)
                acted_on, _ = act_with.predict(features.vector(float(info["time_s"]), last[0]))
            planned, _ = controller.predict(acted_on, deterministic=True)
            noise = rng.normal(0.0, ACTION_NOISE_RAD, 2)
            action = np.clip(planned + noise, box.low, box.high)
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
    """Record ``episodes`` training episodes (estimation/ball_table/learned.py's
    docstring) of up to ``steps`` steps into the new folder ``out_dir``: each draws its
    sensor from :data:`TRAINING_RANGES` and then its world's seed, from ``seed``; the
    :func:`player` acts. Returns what its ``record.json`` holds."""
    from observer_gym.train.experiments.record import record_played
    from observer_gym.train.rl.randomize import randomize_of_ranges

    return record_played(
        "BallTable-v0",
        OBSERVER,
        out_dir,
        randomize=randomize_of_ranges(TRAINING_RANGES),
        episodes=episodes,
        seed=seed,
        steps=steps,
        player=player(act_with),
        player_name="lqr-on-truth" if act_with is None else "lqr-on-learned",
        config={"action_noise_rad": ACTION_NOISE_RAD},
    )


def collect(
    episodes: int,
    seed: int,
    steps: int = EPISODE_STEPS,
    act_with: Any = None,
    out_dir: str | Path | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(features (N, 58), truth (N, 8), episode (N,)) from ``episodes`` training episodes
    of up to ``steps`` steps (estimation/ball_table/learned.py's docstring), reproducible
    from ``seed``: recorded (:func:`record_episodes`) into the new folder ``out_dir`` (a
    temporary one, removed after, if None) and read back
    (:func:`~observer_gym.train.experiments.learned_observers.recorded.training_arrays`).
    With ``act_with`` (a :class:`~observer_gym.estimation.learned.network.GaussianMLP`)
    the LQR acts on that network's estimate instead of the truth: the states the
    network's own errors lead to (the data of a DAgger round)."""
    from observer_gym.train.experiments.learned_observers.recorded import training_arrays

    if out_dir is not None:
        record_episodes(out_dir, episodes, seed, steps, act_with)
        return training_arrays("BallTable-v0", out_dir)
    with tempfile.TemporaryDirectory(prefix="ball_table-collect-") as tmp:
        folder = Path(tmp) / "recording"
        record_episodes(folder, episodes, seed, steps, act_with)
        return training_arrays("BallTable-v0", folder)


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
