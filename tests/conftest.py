"""Shared fixtures: every env a test makes is closed, whatever the test's outcome.

The toy fourth system of tests/toy_system is registered here, before collection, so the
env suite (tests/envs/test_envs.py, test_copies.py) runs on it beside the package's.
"""

from __future__ import annotations

import gymnasium as gym
import pytest
import toy_system

import observer_gym.envs

toy_system.register()
ENV_IDS = observer_gym.envs.ENV_IDS
# every registered system's env: the package's and the toy
SUITE_IDS = tuple(system.env_id for system in observer_gym.envs.SYSTEMS)
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
