"""BallTable's ``belief`` features (train/rl/features/ball_table.py): the state entries and
the standard deviations the observer's covariance claims."""

from __future__ import annotations

import numpy as np
import pytest

from observer_gym.train.rl.agent_env import make_agent_env
from observer_gym.train.rl.features import wrap_features

BT = "observer_gym/BallTable-v0"


def test_the_estimate_is_followed_by_the_square_root_of_its_covariances_diagonal():
    env = make_agent_env(BT, "estimate", observer="kf-latency-measurements", features="belief")
    try:
        assert env.observation_space.shape == (16,)
        obs, info = env.reset(seed=2)
        for _ in range(30):
            obs, _, _, _, info = env.step(env.action_space.sample())
            estimate = info["estimate"]
            np.testing.assert_allclose(obs[:8], estimate["mean"], rtol=1e-6, atol=1e-7)
            std = np.sqrt(np.diag(estimate["covariance"]))
            high = env.observation_space.high[8:]
            np.testing.assert_allclose(obs[8:], np.minimum(std, high), rtol=1e-6, atol=1e-9)
            assert np.all(obs[8:] > 0.0)  # a filter is never certain
            assert env.observation_space.contains(obs)
    finally:
        env.close()


def test_the_true_state_is_certain():
    env = make_agent_env(BT, "state", features="belief")
    try:
        obs, _ = env.reset(seed=0)
        obs, *_ = env.step(env.action_space.sample())
        assert np.all(obs[8:] == 0.0)
    finally:
        env.close()


def test_a_non_state_layout_is_refused():
    env = make_agent_env(BT, "measurements")
    try:
        with pytest.raises(ValueError, match="features 'belief' need the state's layout"):
            wrap_features(env, "belief")
    finally:
        env.close()
