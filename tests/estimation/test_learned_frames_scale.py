"""BallTable's ``learned`` from rendered frames reports its network's variance times the
weight file's ``"rgb"`` variance scale (estimation/learned/variance_scale.py), not the
``"measurements"`` one and not the network's own."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np

from observer_gym.estimation import VisionObserver
from observer_gym.estimation.ball_table.learned import WEIGHTS
from observer_gym.estimation.learned.variance_scale import load_variance_scale


def test_learned_from_frames_reports_the_networks_variance_times_the_rgb_scale():
    report = json.loads(WEIGHTS.with_suffix(".json").read_text())
    scales = {mode: load_variance_scale(report, mode, 8) for mode in ("rgb", "measurements")}
    env = VisionObserver(gym.make("observer_gym/BallTable-v0", obs_mode="rgb"), observer="learned")
    try:
        env.reset(seed=0)
        _, _, _, _, info = env.step(np.zeros(2, dtype=np.float32))
        observer = env.pipeline  # the LearnedObserver
        assert observer.detector is not None  # it reads the frames
        now_s = float(info["time_s"])
        features = observer.features.vector(now_s, np.zeros(2))
        _, raw = observer.net.predict(features)
        age_s = observer.features.newest_age_s(now_s)
        rgb, measurements = scales["rgb"].at(age_s), scales["measurements"].at(age_s)
        # the two scales differ in every entry and from 1, so the check below tells them apart
        assert np.all(np.abs(rgb / measurements - 1.0) > 0.05)
        assert np.all(np.abs(rgb - 1.0) > 0.05)
        reported = np.diag(info["estimate"]["covariance"])
        assert np.allclose(reported, np.diag(raw) * rgb)
    finally:
        env.close()
