"""What an agent reads and how its actions map back; the shipped hyperparameters."""

from __future__ import annotations

import cv2
import gymnasium as gym
import numpy as np
import pytest
from gymnasium.wrappers import RescaleAction
from stable_baselines3.common.preprocessing import is_image_space

from observer_gym.envs import ENV_IDS
from observer_gym.train.rl.agent_env import (
    ImageOptions,
    make_agent_env,
    observer_for,
    to_env_action,
)
from observer_gym.train.rl.hyperparams import ALGOS, load_hyperparams, split


def test_observer_for_each_obs():
    env_id = "observer_gym/BallTable-v0"
    assert observer_for(env_id, "state") == "oracle"
    assert observer_for(env_id, "estimate") == "kf-measurements"
    assert observer_for(env_id, "estimate", "rgb") == "kf"
    assert observer_for(env_id, "rgb") == "pixels"
    assert observer_for("observer_gym/TargetFollower-v0", "estimate") == "stkf-measurements"
    with pytest.raises(ValueError, match="unknown estimate_from"):
        observer_for(env_id, "estimate", "depth")


def test_an_estimating_observer_can_be_named():
    env_id = "observer_gym/BallTable-v0"
    assert observer_for(env_id, "estimate", observer="kf") == "kf"
    for wrong in ("oracle", "pixels", "nope"):
        with pytest.raises(ValueError, match="allowed: kf, kf-measurements"):
            observer_for(env_id, "estimate", observer=wrong)
    with pytest.raises(ValueError, match="--obs estimate only"):
        observer_for(env_id, "state", observer="kf")


def test_agent_actions_map_back_as_rescale_action_does():
    """to_env_action inverts the [-1, 1] rescaling the agent trained through."""
    env = gym.make("observer_gym/BallCatcher-v1", obs_mode="state")
    try:
        rescaled = RescaleAction(env, np.float32(-1.0), np.float32(1.0))
        low, high = env.action_space.low, env.action_space.high
        rng = np.random.default_rng(0)
        for action in rng.uniform(-1, 1, size=(50, 3)):
            np.testing.assert_allclose(
                to_env_action(action, low, high), rescaled.action(action), atol=1e-7
            )
        np.testing.assert_array_equal(to_env_action(np.full(3, 7.0), low, high), high)
    finally:
        env.close()


def test_ball_table_frames_resized_grayscale_and_stacked():
    env = make_agent_env("observer_gym/BallTable-v0", "rgb")
    raw = gym.make("observer_gym/BallTable-v0", obs_mode="rgb")
    try:
        assert env.observation_space.shape == (4, 84, 84)
        assert is_image_space(env.observation_space)  # SB3's CnnPolicy reads it as is
        obs, _ = env.reset(seed=2)
        frame, _ = raw.reset(seed=2)
        expected = cv2.cvtColor(
            cv2.resize(frame, (84, 84), interpolation=cv2.INTER_AREA), cv2.COLOR_RGB2GRAY
        )
        for k in range(4):  # the stack starts as four copies of the reset frame
            np.testing.assert_array_equal(obs[k], expected)
        action = np.array([1.0, -1.0], np.float32)  # full tilt, in the agent's units
        obs, *_ = env.step(action)
        frame, *_ = raw.step(raw.action_space.high * action)
        np.testing.assert_array_equal(obs[:3], np.stack([expected] * 3))
        np.testing.assert_array_equal(
            obs[3],
            cv2.cvtColor(
                cv2.resize(frame, (84, 84), interpolation=cv2.INTER_AREA), cv2.COLOR_RGB2GRAY
            ),
        )
        # the green ball stands out from the red table in grayscale
        assert np.ptp(obs[3]) > 60
    finally:
        env.close()
        raw.close()


def test_ball_catcher_frames_in_a_dict():
    env = make_agent_env("observer_gym/BallCatcher-v1", "rgb", image={"frame_stack": 2})
    try:
        space = env.observation_space
        assert set(space.spaces) == {"camera_0", "camera_1", "frame_age_s"}
        assert space["camera_0"].shape == (2, 84, 84) and space["frame_age_s"].shape == (2, 2)
        obs, _ = env.reset(seed=0)
        assert space.contains(obs)
    finally:
        env.close()


def test_image_options_are_checked():
    with pytest.raises(ValueError, match="frame_stack > 1 needs grayscale"):
        ImageOptions(grayscale=False)
    with pytest.raises(ValueError, match="size_px"):
        ImageOptions(size_px=4)
    ImageOptions(grayscale=False, frame_stack=1)


@pytest.mark.parametrize("algo", ALGOS)
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_every_shipped_entry_resolves(env_id, algo):
    """Each YAML entry exists and validates for each obs type; overrides apply."""
    for obs in ("state", "estimate", "rgb"):
        params = load_hyperparams(env_id, algo, obs, {"policy_kwargs.net_arch": [8]})
        training, algo_kwargs = split(params)
        assert training["n_envs"] >= 1 and training["n_timesteps"] >= 1000
        assert algo_kwargs["policy_kwargs"]["net_arch"] == [8]
        assert "n_timesteps" not in algo_kwargs
    with pytest.raises(ValueError, match=r"unknown hyperparameter\(s\) \['n_step'\]"):
        load_hyperparams(env_id, algo, "state", {"n_step": 5})
