"""The input of an agent trained with --obs measurements (train/rl/measurement_input.py):
the newest frame's report, its age and the robot's own kinematics, checked against the
simulator's own delivery records; the stack of the last k; and its refusals."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.train.rl.agent_env import make_agent_env, observer_for
from observer_gym.train.rl.measurement_input import (
    NO_FRAME_AGE_S,
    MeasurementInput,
    check_stack,
    wrap_measurements,
)
from observer_gym.wrappers import FlatObservation

BT = "observer_gym/BallTable-v0"
BC = "observer_gym/BallCatcher-v1"
DELAY = {"latency_s": 0.06, "latency_jitter_s": 0.02, "frame_drop_prob": 0.1}


def _newest_capture_s(env: gym.Env) -> float:
    """The capture time of the camera's newest delivered frame, from the rig itself."""
    base = env.unwrapped
    latest = base.rig.latest[0]
    return -np.inf if latest is None else latest.capture_tick * base.tick_s


def test_ball_table_vector_is_the_report_then_the_newest_frames_age():
    env = MeasurementInput(gym.make(BT, obs_mode="measurements", **DELAY))
    flat = FlatObservation(gym.make(BT, obs_mode="measurements", **DELAY))
    try:
        assert env.observation_space.shape == (14,)
        obs, info = env.reset(seed=3)
        flat_obs, _ = flat.reset(seed=3)
        ages = []
        for _ in range(60):
            action = np.array([0.01, -0.02])
            obs, _, _, _, info = env.step(action)
            flat_obs, *_ = flat.step(action)
            np.testing.assert_array_equal(obs[:13], flat_obs)
            expected = min(info["time_s"] - _newest_capture_s(env), NO_FRAME_AGE_S)
            assert obs[13] == pytest.approx(expected, abs=1e-6)
            assert env.observation_space.contains(obs)
            ages.append(obs[13])
        # 60 ms latency, 20 ms jitter: the newest frame is never younger than the latency
        # minus a few jitters, and its age moves as frames arrive late or are dropped
        assert min(ages) >= 0.0 and np.mean(ages) > 0.05 and np.ptp(ages) > 0.015
    finally:
        env.close()
        flat.close()


def test_ball_table_age_at_zero_latency_is_zero():
    env = MeasurementInput(gym.make(BT, obs_mode="measurements"))
    try:
        env.reset(seed=0)
        for _ in range(10):
            obs, *_ = env.step(np.zeros(2))
            assert obs[13] == 0.0  # one frame per step, captured at the step's end
    finally:
        env.close()


def test_ball_catcher_keeps_its_frame_ages_and_adds_the_box_kinematics():
    env = MeasurementInput(gym.make(BC, obs_mode="measurements", **DELAY))
    try:
        n = env.unwrapped.num_cameras
        assert env.observation_space.shape == (4 * n + 6,)
        obs, info = env.reset(seed=1)
        for _ in range(20):
            obs, _, terminated, truncated, info = env.step(np.zeros(env.action_space.shape))
            np.testing.assert_allclose(obs[4 * n : 4 * n + 3], info["box_pos_world_m"], atol=1e-6)
            np.testing.assert_allclose(obs[4 * n + 3 :], info["box_vel_world_mps"], atol=1e-6)
            if terminated or truncated:
                break
    finally:
        env.close()


def test_a_stack_holds_the_last_k_vectors_oldest_first():
    single = MeasurementInput(gym.make(BT, obs_mode="measurements", **DELAY))
    stacked = wrap_measurements(gym.make(BT, obs_mode="measurements", **DELAY), 3)
    try:
        assert stacked.observation_space.shape == (3 * 14,)
        first, _ = single.reset(seed=5)
        obs, _ = stacked.reset(seed=5)
        np.testing.assert_array_equal(obs.reshape(3, 14), np.stack([first] * 3))  # padded
        history = [first, first]
        for _ in range(8):
            action = np.array([0.02, 0.0])
            vector, *_ = single.step(action)
            obs, *_ = stacked.step(action)
            history.append(vector)
            np.testing.assert_array_equal(obs.reshape(3, 14), np.stack(history[-3:]))
    finally:
        single.close()
        stacked.close()


@pytest.mark.parametrize("bad", [0, 17, 2.5, True, "4", None])
def test_a_bad_stack_is_refused_naming_the_hyperparameter(bad):
    with pytest.raises(ValueError, match=r"measurement_stack must be an integer in \[1, 16\]"):
        check_stack(bad)


def test_the_agent_env_reads_the_detections_observer():
    assert observer_for(BT, "measurements") == "detections"
    env = make_agent_env(BT, "measurements", env_kwargs=DELAY, measurement_stack=2)
    try:
        assert env.observation_space.shape == (28,)
        obs, _ = env.reset(seed=0)
        assert obs.shape == (28,)
        assert np.all(env.action_space.high == 1.0)  # rescaled for the policy
    finally:
        env.close()


def test_features_do_not_apply_to_measurements(tmp_path):
    from observer_gym.train.rl.training import check_features

    with pytest.raises(ValueError, match="needs --obs state or estimate, not measurements"):
        check_features(BC, "measurements", "crossing")
