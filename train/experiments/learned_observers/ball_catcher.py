"""BallCatcher's training data for its learned observer and its learned detector: the
``intercept`` controller catches the throws (estimation/ball_catcher/learned.py and
learned_detector.py describe the data, its ranges and the networks fitted on it)."""

from __future__ import annotations

import math
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np

from observer_gym.controllers import make_controller
from observer_gym.controllers.ball_catcher import InterceptController
from observer_gym.envs.ball_catcher import BallCatcherEnv
from observer_gym.estimation.ball_catcher import learned_detector
from observer_gym.estimation.ball_catcher.frames import FrameReader
from observer_gym.estimation.ball_catcher.learned import (
    TRAINING_RANGES,
    LearnedFeatures,
    image_centre_px,
)
from observer_gym.estimation.ball_catcher.state_layout import state_estimate
from observer_gym.train.rl.randomize import randomize_of_ranges

if TYPE_CHECKING:  # frame_training imports torch, which importing this module must not
    from observer_gym.estimation.learned.frame_training import FrameDataset

__all__ = ["collect", "collect_frames", "frame_samples", "player", "record_episodes"]


# the observer whose env a training recording keeps: the measurements, no filter
OBSERVER = "detections"


def player(act_with: Any = None) -> Any:
    """The training throws' player (:func:`~observer_gym.train.experiments.record.
    record_played`): the ``intercept`` controller on the truth, or with ``act_with`` (a
    :class:`~observer_gym.estimation.learned.network.GaussianMLP`) on that network's
    estimate and covariance (a DAgger round); no action noise."""

    def policy_for(world: gym.Env, rng: np.random.Generator) -> Any:
        unwrapped = world.unwrapped
        assert isinstance(unwrapped, BallCatcherEnv)
        controller = make_controller("intercept", world)
        assert isinstance(controller, InterceptController)
        pixels = FrameReader(unwrapped.config, owner="collect")
        features = LearnedFeatures(unwrapped.num_cameras, image_centre_px(unwrapped))

        def act(obs: Any, info: Any) -> np.ndarray:
            if act_with is None:
                acted_on = np.asarray(info["state"], dtype=float)
            else:
                for frame in info["frames"]:
                    uv = pixels.detect(frame)
                    features.add(int(frame["camera_id"]), float(frame["capture_time_s"]), uv)
                ball, ball_covariance = act_with.predict(features.vector(float(info["time_s"])))
                acted_on, covariance = state_estimate(ball, ball_covariance, info)
                controller.observe_info({"estimate": {"covariance": covariance}})
            action, _ = controller.predict(acted_on, deterministic=True)
            return action

        return act

    return policy_for


def record_episodes(
    out_dir: str | Path, episodes: int, seed: int, act_with: Any = None
) -> dict[str, Any]:
    """Record ``episodes`` training throws (estimation/ball_catcher/learned.py's
    docstring) into the new folder ``out_dir``: each draws its sensor from
    :data:`TRAINING_RANGES` and then its world's seed, from ``seed``; the :func:`player`
    acts to the throw's end. Returns what its ``record.json`` holds."""
    from observer_gym.train.experiments.record import record_played

    return record_played(
        "BallCatcher-v1",
        OBSERVER,
        out_dir,
        randomize=randomize_of_ranges(TRAINING_RANGES),
        episodes=episodes,
        seed=seed,
        steps=None,
        player=player(act_with),
        player_name="intercept-on-truth" if act_with is None else "intercept-on-learned",
        config={},
    )


def collect(
    episodes: int, seed: int, act_with: Any = None, out_dir: str | Path | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(features (N, 65), truth (N, 6): the ball's position and velocity, episode (N,))
    from ``episodes`` throws (estimation/ball_catcher/learned.py's docstring), the
    free-flight steps only, reproducible from ``seed``: recorded
    (:func:`record_episodes`) into the new folder ``out_dir`` (a temporary one, removed
    after, if None) and read back
    (:func:`~observer_gym.train.experiments.learned_observers.recorded.training_arrays`).
    The ``intercept`` controller acts on the truth, or with ``act_with`` (a
    :class:`~observer_gym.estimation.learned.network.GaussianMLP`) on that network's
    estimate and covariance (a DAgger round)."""
    from observer_gym.train.experiments.learned_observers.recorded import training_arrays

    if out_dir is not None:
        record_episodes(out_dir, episodes, seed, act_with)
        return training_arrays("BallCatcher-v1", out_dir)
    with tempfile.TemporaryDirectory(prefix="ball_catcher-collect-") as tmp:
        folder = Path(tmp) / "recording"
        record_episodes(folder, episodes, seed, act_with)
        return training_arrays("BallCatcher-v1", folder)


def _crop(
    image: np.ndarray, uv_px: np.ndarray | None, x0: int, y0: int, width: int, height: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(crop (3, height, width), the ball's (u, v) in it (zeros if not in it), detected
    (1,))."""
    crop = np.ascontiguousarray(image[y0 : y0 + height, x0 : x0 + width].transpose(2, 0, 1))
    if uv_px is None:
        return crop, np.zeros(2), np.zeros(1)
    uv = np.asarray(uv_px, float) - (x0, y0)
    inside = bool(np.all(uv >= 0.0) and uv[0] <= width - 1 and uv[1] <= height - 1)
    return crop, uv if inside else np.zeros(2), np.array([float(inside)])


def frame_samples(crop_px: int | None) -> Any:
    """collect_lockstep's ``samples_of``: every frame delivered in the step (paired with
    the measurement env's same frame), as two crops (estimation/ball_catcher/
    learned_detector.py's docstring) or, with ``crop_px`` None, whole (3, 240, 320) with
    its full-frame label."""

    def samples_of(
        obs: Any, info: dict, measurement: Any, measured_info: dict, rng: np.random.Generator
    ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        out = []
        for frame, measured in zip(info["frames"], measured_info["frames"], strict=True):
            if (frame["camera_id"], frame["capture_time_s"]) != (
                measured["camera_id"],
                measured["capture_time_s"],
            ):
                raise RuntimeError("the lockstep envs delivered different frames")
            image, uv = frame["image"], measured["uv_px"]
            height, width = image.shape[:2]
            if crop_px is None:
                out.append(_crop(image, uv, 0, 0, width, height))
                continue
            if uv is not None:  # the ball uniformly within the crop, the crop in the frame
                x0 = math.floor(uv[0] - rng.uniform(0.0, crop_px))
                y0 = math.floor(uv[1] - rng.uniform(0.0, crop_px))
                x0, y0 = min(max(x0, 0), width - crop_px), min(max(y0, 0), height - crop_px)
                out.append(_crop(image, uv, x0, y0, crop_px, crop_px))
            x0 = int(rng.integers(width - crop_px + 1))
            y0 = int(rng.integers(height - crop_px + 1))
            out.append(_crop(image, uv, x0, y0, crop_px, crop_px))
        return out

    return samples_of


def collect_frames(
    episodes: int,
    seed: int,
    steps: int = learned_detector.EPISODE_STEPS,
    crop_px: int | None = learned_detector.CROP_PX,
) -> FrameDataset:
    """A :class:`~observer_gym.estimation.learned.frame_training.FrameDataset` of
    ``episodes`` lockstep throws (estimation/ball_catcher/learned_detector.py's
    docstring), reproducible from ``seed``: values the ball's (u, v) in px of the crop
    (or, ``crop_px`` None, of the whole frame), detected (N, 1)."""
    from observer_gym.train.experiments.learned_observers.frame_data import collect_lockstep

    return collect_lockstep(
        "observer_gym/BallCatcher-v1",
        episodes,
        seed,
        steps=steps,
        stride=learned_detector.STRIDE,
        ranges=learned_detector.FRAME_RANGES,
        controller="intercept",
        noise_range=learned_detector.ACTION_NOISE_RANGE_MPS,
        env_kwargs=learned_detector.ENV_KWARGS,
        samples_of=frame_samples(crop_px),
    )
