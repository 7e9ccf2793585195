"""Observation features for agents (``features: NAME``): BallCatcher's ``crossing``
against closed forms, TargetFollower's ``tracking`` against the env's reward, and the
checks of the name."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from observer_gym.envs.ball_catcher import geometry as geo
from observer_gym.envs.ball_catcher.throws import throw_through
from observer_gym.envs.sim import GRAVITY_MPS2
from observer_gym.train.rl.agent_env import make_agent_env
from observer_gym.train.rl.features import feature_names, wrap_features
from observer_gym.train.rl.features.ball_catcher import FEATURE_NAMES, CrossingFeatures
from observer_gym.train.rl.features.target_follower import FEATURE_NAMES as TRACKING_NAMES
from observer_gym.train.rl.features.target_follower import TrackingFeatures
from observer_gym.train.rl.training import check_features


@pytest.fixture
def crossing_env():
    env = CrossingFeatures(gym.make("observer_gym/BallCatcher-v1", obs_mode="state"))
    yield env
    env.close()


def test_crossing_at_reset_is_the_throws_aim(crossing_env):
    """A throw aimed (drag-free) at point c of the box's home plane after T seconds: at
    launch, with the box at home, the features are the crossing of the observed state,
    c' = p + v t - (0, 0, g t^2 / 2) with t = (b_x - p_x) / v_x, relative to the hole;
    c' is c to within the integrator's half-tick velocity offset (g dt / 2 T, 2.2 mm)."""
    aim = geo.HOLE_HOME_WORLD + np.array([0.0, 0.031, -0.024])
    throw = throw_through([3.1, 0.05, 0.6], aim, 0.44)
    features, info = crossing_env.reset(
        seed=0, options={"throw": (throw.launch_pos_world, throw.launch_vel_world)}
    )
    state = info["state"].astype(float)
    p, v, b = state[0:3], state[3:6], state[6:9]
    t_s = (b[0] - p[0]) / v[0]
    crossing = p + v * t_s - np.array([0.0, 0.0, 0.5 * GRAVITY_MPS2 * t_s**2])
    assert features.shape == (len(FEATURE_NAMES),)
    named = dict(zip(FEATURE_NAMES, features.tolist(), strict=True))
    assert named["miss_y_m"] == pytest.approx(crossing[1] - b[1], abs=1e-6)
    assert named["miss_z_m"] == pytest.approx(crossing[2] - b[2], abs=1e-6)
    assert named["time_to_plane_s"] == pytest.approx(t_s, abs=1e-6)
    assert named["approaching"] == 1.0 and named["miss_std_m"] == 0.0
    np.testing.assert_allclose([named["miss_y_m"], named["miss_z_m"]], [0.031, -0.024], atol=3e-3)
    assert named["time_to_plane_s"] == pytest.approx(0.44, abs=1e-3)
    np.testing.assert_allclose(features[5:], 0.0, atol=1e-6)  # the box at home, at rest
    assert crossing_env.observation_space.contains(features)


def test_crossing_std_is_the_propagated_covariance(crossing_env):
    """Only the ball's y position uncertain (sigma): the crossing's y has dc_y/dp_y = 1
    and c_z does not depend on it, so its standard deviation is sigma. Only v_y
    uncertain: dc_y/dv_y = t, so sigma t."""
    state = np.zeros(12)
    state[0:3] = [2.7, 0.0, 0.5]
    state[3:6] = [-5.0, 0.0, 1.0]
    state[6:9] = geo.HOLE_HOME_WORLD
    t_s = (state[6] - state[0]) / state[3]
    for index, expected in ((1, 0.02), (4, 0.02 * t_s)):
        covariance = np.zeros((12, 12))
        covariance[index, index] = 0.02**2
        features = crossing_env.features(state, {"estimate": {"covariance": covariance}})
        assert features[4] == pytest.approx(expected, rel=1e-6)


def test_no_crossing_when_the_ball_moves_away(crossing_env):
    state = np.zeros(12)
    state[0:3] = [1.5, 0.0, 0.5]
    state[3:6] = [2.0, 0.0, 1.0]  # away from the plane
    state[6:9] = geo.HOLE_HOME_WORLD + np.array([0.0, 0.1, 0.0])
    state[9:12] = [0.0, 0.2, 0.0]
    features = crossing_env.features(state, {})
    np.testing.assert_array_equal(features[:5], 0.0)
    np.testing.assert_allclose(features[5:], [0.0, 0.1, 0.0, 0.0, 0.2, 0.0], atol=1e-7)


def test_the_agent_env_reads_the_features_of_the_estimate():
    env = make_agent_env("observer_gym/BallCatcher-v1", "estimate", features="crossing")
    try:
        features, _ = env.reset(seed=3)
        assert env.observation_space.shape == (11,)
        for _ in range(20):
            features, *_ = env.step(np.zeros(3, np.float32))
        assert features[3] == 1.0 and features[4] > 0.0  # an estimate has a covariance
    finally:
        env.close()


def test_feature_names_are_checked():
    assert feature_names("ball_catcher") == ("crossing",)
    assert feature_names("ball_table") == ("belief",)
    env = gym.make("observer_gym/BallTable-v0", obs_mode="state")
    try:
        with pytest.raises(ValueError, match="unknown features 'crossing' for BallTable-v0"):
            wrap_features(env, "crossing")
    finally:
        env.close()
    with pytest.raises(ValueError, match="allowed: crossing"):
        check_features("observer_gym/BallCatcher-v1", "estimate", "nope")
    with pytest.raises(ValueError, match="not rgb"):
        check_features("observer_gym/BallCatcher-v1", "rgb", "crossing")
    with pytest.raises(ValueError, match="need the state's layout"):
        make_agent_env("observer_gym/BallCatcher-v1", "rgb", features="crossing")


def test_tracking_errors_are_the_rewards_terms():
    """TargetFollower's ``tracking`` on the true state: its first three entries are the
    reward's terms, so at every step reward = 1 - mean_j min(|f_j|, 1) while the target
    is on the image (envs/target_follower/env.py, Rewards)."""
    env = wrap_features(gym.make("observer_gym/TargetFollower-v0", obs_mode="state"), "tracking")
    try:
        features, info = env.reset(seed=5)
        rng = np.random.default_rng(0)
        for _ in range(40):
            action = rng.uniform(env.action_space.low, env.action_space.high).astype(np.float32)
            features, reward, terminated, truncated, info = env.step(action)
            assert env.observation_space.contains(features)
            assert features.shape == (len(TRACKING_NAMES),)
            if info["target_in_image"]:
                expected = 1.0 - np.mean(np.minimum(np.abs(features[:3].astype(float)), 1.0))
                assert reward == pytest.approx(expected, abs=1e-6)
            state = info["state"]
            assert features[TRACKING_NAMES.index("tilt_rad")] == pytest.approx(state[9], abs=1e-6)
            np.testing.assert_allclose(features[-2:], state[13:15])
            if terminated or truncated:
                break
    finally:
        env.close()


def test_tracking_reads_no_robot_pose():
    """Two states that differ only in the robot's pose on the floor (x, y, yaw) give the
    same features; the image rates are scaled as the errors are."""
    env = TrackingFeatures(gym.make("observer_gym/TargetFollower-v0", obs_mode="state"))
    try:
        _, info = env.reset(seed=1)
        state = np.asarray(info["state"], dtype=float)
        moved = state.copy()
        moved[6:9] = [3.0, -2.0, 1.2]
        np.testing.assert_array_equal(env.features(state), env.features(moved))
        rate = env.features(state)[3:6]
        np.testing.assert_allclose(rate, np.clip(state[3:6] / env.scale_px, -30, 30), rtol=1e-6)
    finally:
        env.close()
