"""Shared fixtures: every env a test makes is closed, whatever the test's outcome."""

from __future__ import annotations

import gymnasium as gym
import pytest

import observer_gym.envs

ENV_IDS = observer_gym.envs.ENV_IDS
OBS_MODES = ("rgb", "state", "measurements")


@pytest.fixture
def make_env():
    """``make_env(env_id, **kwargs)`` -> a gym.make'd env, closed at teardown."""
    made = []

    def factory(env_id: str = "observer_gym/BallTable-v0", **kwargs):
        env = gym.make(env_id, **kwargs)
        made.append(env)
        return env

    yield factory
    for env in made:
        env.close()
