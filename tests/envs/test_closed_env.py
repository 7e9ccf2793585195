"""A closed env: after ``close()``, ``step``, ``render``, ``camera_pose`` and the world's
ground truth raise ``EnvClosedError`` (a ``gymnasium.error.ClosedEnvironmentError`` and a
``RuntimeError``) naming what to do, until ``reset()``, which builds a new world equal to
a fresh env's (envs/core.py)."""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest
from gymnasium.error import ClosedEnvironmentError
from gymnasium.utils.env_checker import data_equivalence

import observer_gym.envs

ENV_IDS = observer_gym.envs.ENV_IDS
SMALL = {"image_width_px": 80, "image_height_px": 60}


def _zero_action(env) -> np.ndarray:
    return np.zeros(env.action_space.shape, env.action_space.dtype)


def _calls(env) -> dict:
    """Every call that reads or moves the world, by name."""
    unwrapped = env.unwrapped
    return {
        "step()": lambda: env.step(_zero_action(env)),
        "render()": env.render,
        "camera_pose()": lambda: unwrapped.camera_pose(0),
        "scene.ground_truth()": unwrapped.scene.ground_truth,
    }


@pytest.mark.parametrize("obs_mode", ["rgb", "state"])
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_every_use_of_a_closed_env_raises_one_clear_error(make_env, env_id, obs_mode):
    env = make_env(env_id, obs_mode=obs_mode, render_mode="rgb_array", **SMALL)
    env.reset(seed=0)
    env.step(_zero_action(env))
    env.close()
    for name, call in _calls(env).items():
        with pytest.raises(ClosedEnvironmentError, match=r"closed.*call reset\(\)") as info:
            call()
        assert type(info.value).__name__ == "EnvClosedError", name
        assert isinstance(info.value, RuntimeError), name


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_reset_after_close_builds_a_world_equal_to_a_fresh_one(make_env, env_id):
    env = make_env(env_id, obs_mode="measurements", render_mode="rgb_array", **SMALL)
    fresh = make_env(env_id, obs_mode="measurements", render_mode="rgb_array", **SMALL)
    env.reset(seed=1)
    env.step(env.action_space.sample())
    env.close()
    with pytest.raises(ClosedEnvironmentError):
        env.step(_zero_action(env))
    assert data_equivalence(env.reset(seed=3), fresh.reset(seed=3))
    for _ in range(3):
        action = env.action_space.sample()
        assert data_equivalence(env.step(action), fresh.step(action))
    assert np.array_equal(env.render(), fresh.render())


def test_close_before_any_reset_asks_for_a_reset(make_env):
    env = make_env("observer_gym/BallTable-v0", obs_mode="state")
    env.close()
    with pytest.raises(ClosedEnvironmentError, match=r"call reset\(\)"):
        env.unwrapped.step(_zero_action(env))
    env.reset(seed=0)
    env.step(_zero_action(env))


@pytest.mark.parametrize("copier", [copy.deepcopy, lambda e: pickle.loads(pickle.dumps(e))])
def test_a_copy_of_a_closed_env_is_closed_until_reset(make_env, copier):
    env = make_env("observer_gym/TargetFollower-v0", obs_mode="state")
    fresh = make_env("observer_gym/TargetFollower-v0", obs_mode="state")
    env.reset(seed=0)
    env.step(_zero_action(env))
    env.close()
    twin = copier(env.unwrapped)
    try:
        with pytest.raises(ClosedEnvironmentError):
            twin.step(_zero_action(env))
        assert data_equivalence(twin.reset(seed=2), fresh.reset(seed=2))
    finally:
        twin.close()
