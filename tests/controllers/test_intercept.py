"""The intercept controller: its crossing prediction against closed forms and finite
differences, its motion within the profile, holding while uncertain, and catches."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.controllers import make_controller
from observer_gym.controllers.ball_catcher.intercept import crossing_and_jacobian
from observer_gym.envs.ball_catcher.throws import plane_crossing

ENV_ID = "observer_gym/BallCatcher-v1"
G = 9.81


def test_crossing_matches_the_env_and_its_jacobian_matches_finite_differences():
    rng = np.random.default_rng(0)
    for _ in range(20):
        ball = np.concatenate(
            [rng.uniform([2.0, -0.3, 0.4], [3.5, 0.3, 0.8]), rng.uniform([-7, -1, 0], [-4, 1, 4])]
        )
        t, point, J = crossing_and_jacobian(ball, 0.7, G)
        t_env, point_env = plane_crossing(ball[:3], ball[3:], 0.7, G)
        assert t == pytest.approx(t_env) and np.allclose(point, point_env)
        assert point[0] == pytest.approx(0.7)
        numeric = np.empty((2, 6))
        for i in range(6):
            step = np.zeros(6)
            step[i] = 1e-6
            plus = crossing_and_jacobian(ball + step, 0.7, G)[1][1:]
            minus = crossing_and_jacobian(ball - step, 0.7, G)[1][1:]
            numeric[:, i] = (plus - minus) / 2e-6
        np.testing.assert_allclose(J, numeric, rtol=1e-6, atol=1e-8)


def test_no_crossing_for_a_ball_moving_away():
    assert crossing_and_jacobian(np.array([2.0, 0, 1, 3.0, 0, 0]), 0.7, G) is None
    assert crossing_and_jacobian(np.array([0.5, 0, 1, -3.0, 0, 0]), 0.7, G) is None


@pytest.fixture
def env():
    env = gym.make(ENV_ID, obs_mode="state")
    yield env
    env.close()


def test_moves_toward_the_crossing_within_the_profile_and_holds_while_uncertain(env):
    controller = make_controller("intercept", env)
    obs, info = env.reset(seed=5)
    crossing = info["throw"]["crossing_pos_world"]
    action, _ = controller.predict(obs)
    direction = (crossing - obs[6:9])[1:]
    assert np.dot(action[1:], direction) > 0.0  # toward it
    assert np.linalg.norm(action) <= 0.5 + 1e-6  # the paper profile's speed
    # A covariance whose crossing std is above hold_std_m: hold still.
    controller.observe_info({"estimate": {"covariance": np.eye(12)}})
    action, _ = controller.predict(obs)
    np.testing.assert_array_equal(action, np.zeros(3, np.float32))
    assert controller.last_crossing_std_m > controller.hold_std_m
    controller.observe_info({"estimate": {"covariance": 1e-8 * np.eye(12)}})
    assert np.linalg.norm(controller.predict(obs)[0]) > 0.0


@pytest.mark.parametrize("profile", ["paper", "fast"])
def test_oracle_intercept_catches_every_throw_of_twelve(profile):
    env = gym.make(ENV_ID, obs_mode="state", robot_profile=profile)
    controller = make_controller("intercept", env)
    outcomes = []
    try:
        for seed in range(12):
            obs, _ = env.reset(seed=seed)
            controller.reset()
            terminated = truncated = False
            while not (terminated or truncated):
                obs, _, terminated, truncated, info = env.step(controller.predict(obs)[0])
            outcomes.append(info["outcome"])
    finally:
        env.close()
    assert outcomes == ["caught"] * 12


def test_intercept_needs_a_ball_catcher_env():
    env = gym.make("observer_gym/BallTable-v0", obs_mode="state")
    try:
        with pytest.raises(ValueError, match="BallCatcher-v1"):
            make_controller("intercept", env)
    finally:
        env.close()


@pytest.mark.parametrize(
    ("option", "value"),
    [("hold_std_m", -1.0), ("brake_fraction", 0.0), ("position_gain_per_s", np.nan)],
)
def test_bad_options_raise(env, option, value):
    with pytest.raises(ValueError, match=option):
        make_controller("intercept", env, **{option: value})
