"""Controllers keep stable-baselines3's predict signature: evaluate_policy scores them,
vector envs get one action per env, bad observations raise."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy

from observer_gym.controllers import CONTROLLERS, Controller, make_controller

ENV_ID = "observer_gym/BallTable-v0"


@pytest.mark.parametrize("name", list(CONTROLLERS))
def test_evaluate_policy_scores_each_controller_above_doing_nothing(name):
    """Two envs in a DummyVecEnv, 4 episodes of 2 s from the default random starts; a
    level table lets the ball roll on, so its return is the baseline."""
    vec_env = make_vec_env(ENV_ID, n_envs=2, seed=0, env_kwargs={"obs_mode": "state"})
    try:
        controller = make_controller(name, vec_env.envs[0])
        assert isinstance(controller, Controller)
        mean_return, _ = evaluate_policy(controller, vec_env, n_eval_episodes=4)

        class Level:
            def predict(self, obs, state=None, episode_start=None, deterministic=True):
                return np.zeros((len(obs), 2), dtype=np.float32), state

        level_return, _ = evaluate_policy(Level(), vec_env, n_eval_episodes=4)
    finally:
        vec_env.close()
    assert mean_return > level_return + 20.0, (mean_return, level_return)


@pytest.mark.parametrize(
    ("obs", "message"),
    [
        (np.zeros(6), r"shape \(6,\)"),
        (np.full(8, np.nan), "not finite"),
        (np.zeros((2, 3)), r"\(2, 3\)"),
    ],
)
def test_bad_observations_raise(make_env, obs, message):
    controller = make_controller("lqr", make_env(obs_mode="state"))
    with pytest.raises(ValueError, match=message):
        controller.predict(obs)


def test_actions_are_float32_in_the_action_space(make_env):
    env = make_env(obs_mode="state")
    controller = make_controller("lqr", env)
    action, state = controller.predict(np.array([0.12, -0.12, 1, 1, 0, 0, 0, 0]))
    assert state is None
    assert action.dtype == np.float32
    assert env.action_space.contains(action)
    assert isinstance(env.action_space, gym.spaces.Box)
