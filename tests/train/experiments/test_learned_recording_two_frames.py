"""BallCatcher's training recording keeps a camera's earlier frame of a step too
(train/reports/dataset.py ``frame_earlier_uv_px``, ``frame_earlier_capture_time_s``):
latency jitter can deliver two frames of one camera in one step, and the reader
(train/experiments/learned_observers/recorded.py) then gives the features the observer
computes at run time from every delivered frame, bit for bit. Before, such a step was
refused, and the training command stopped (at the shipped ranges, at its 35th throw)."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.envs.ball_catcher.layout import BALL
from observer_gym.estimation.ball_catcher.frames import FrameReader
from observer_gym.estimation.ball_catcher.learned import LearnedFeatures, image_centre_px
from observer_gym.train.experiments.learned_observers import ball_catcher
from observer_gym.train.rl.randomize import randomize_of_ranges

pytest.importorskip("minari")

# fixed options under which steps deliver two frames of one camera (measured: a few per
# throw of seeds 0-3 at 5 ms of latency with these jitters)
OPTIONS: dict[str, tuple[Any, ...]] = {
    "measurement_noise_px": (1.0, 1.0),
    "latency_s": (0.005, 0.005),
    "latency_jitter_s": (0.003, 0.003),
    "jitter_s": (0.002, 0.002),
    "camera_preset": ("alternating",),
}


def _in_memory(episode: Any) -> tuple[np.ndarray, np.ndarray, int]:
    """The features of every free-flight step from the frames the env delivered (as the
    observer reads them), replaying the recorded actions; and the steps with two frames
    of one camera."""
    env = gym.make("observer_gym/BallCatcher-v1", obs_mode="measurements", **episode.drawn_options)
    try:
        base: Any = env.unwrapped
        pixels = FrameReader(base.config, owner="test")
        features = LearnedFeatures(base.num_cameras, image_centre_px(base))
        _, info = env.reset(seed=episode.seed)
        xs, ys, doubled = [], [], 0
        for action in episode.actions:  # each step's features before its action
            cameras = [int(f["camera_id"]) for f in info["frames"]]
            doubled += len(cameras) != len(set(cameras))
            for frame in info["frames"]:
                features.add(
                    int(frame["camera_id"]), float(frame["capture_time_s"]), pixels.detect(frame)
                )
            if info["ball_in_flight"]:
                xs.append(features.vector(float(info["time_s"])))
                ys.append(np.asarray(info["state"][BALL], dtype=float))
            _, _, _, _, info = env.step(action)
    finally:
        env.close()
    return np.array(xs), np.array(ys), doubled


def test_a_step_with_two_frames_of_one_camera_is_read_as_the_observer_reads_it(tmp_path):
    from observer_gym.train.experiments.learned_observers.recorded import training_arrays
    from observer_gym.train.experiments.record import record_played
    from observer_gym.train.reports.dataset import read_recording

    record_played(
        "BallCatcher-v1",
        ball_catcher.OBSERVER,
        tmp_path / "data",
        randomize=randomize_of_ranges(OPTIONS),
        episodes=4,
        seed=0,
        steps=None,
        player=ball_catcher.player(),
        player_name="intercept-on-truth",
        config={},
    )
    episodes = read_recording(tmp_path / "data")
    assert max(int(e.infos["frame_count"].max()) for e in episodes) == 2
    x, y, index = training_arrays("BallCatcher-v1", tmp_path / "data")
    doubled = 0
    for k, episode in enumerate(episodes):
        expected_x, expected_y, n = _in_memory(episode)
        doubled += n
        np.testing.assert_array_equal(x[index == k], expected_x)
        np.testing.assert_array_equal(y[index == k], expected_y)
    assert doubled > 0
