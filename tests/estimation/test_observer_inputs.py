"""Bad inputs to BallTable's and TargetFollower's observer pipelines (BallCatcher's are in
test_ball_catcher_observer.py): non-finite measurements are missed detections, frames of
the wrong shape or dtype raise a ValueError naming the expected and the given ones."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.envs.ball_table.layout import BALL_PX
from observer_gym.envs.ball_table.layout import DETECTED as BT_DETECTED
from observer_gym.envs.target_follower import DETECTED as TF_DETECTED
from observer_gym.envs.target_follower import TARGET_PX
from observer_gym.estimation import default_pipeline

BALL_TABLE = "observer_gym/BallTable-v0"
TARGET_FOLLOWER = "observer_gym/TargetFollower-v0"
BAD_STEPS = range(3, 9)  # the steps whose measurement is replaced


def ball_not_seen(obs):
    detected = np.array(obs[BT_DETECTED])
    detected[1] = 0
    return {**obs, BT_DETECTED: detected}


def target_not_seen(obs):
    return {**obs, TF_DETECTED: np.zeros_like(obs[TF_DETECTED])}


def with_values(key, index, value):
    def change(obs):
        array = np.array(obs[key])
        array[index] = value
        return {**obs, key: array}

    return change


def run(env_id, change, steps=14, seed=0):
    """The pipeline's estimates over ``steps`` steps at zero action, the measurement of the
    steps in BAD_STEPS passed through ``change``; and the pipeline."""
    env = gym.make(env_id, obs_mode="measurements").unwrapped
    try:
        pipeline = default_pipeline(env)
        zero = np.zeros(env.action_space.shape, np.float32)
        obs, info = env.reset(seed=seed)
        estimates = [pipeline.observe(obs, info, None)]
        for k in range(steps):
            obs, *_, info = env.step(zero)
            seen = change(obs) if k in BAD_STEPS else obs
            estimates.append(pipeline.observe(seen, info, zero))
    finally:
        env.close()
    return estimates, pipeline


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("index", [0, 1, 2])
def test_ball_table_non_finite_ball_pixel_is_no_detection(bad, index):
    """Before: three in a row counted as gate rejections, and the re-acquisition then
    restarted the ball filter from a NaN position (every later estimate NaN)."""
    estimates, pipeline = run(BALL_TABLE, with_values(BALL_PX, index, bad))
    expected, _ = run(BALL_TABLE, ball_not_seen)
    assert pipeline.reacquisitions == 0
    for got, want in zip(estimates, expected, strict=True):
        assert np.all(np.isfinite(got.mean)) and np.all(np.isfinite(got.covariance))
        np.testing.assert_array_equal(got.mean, want.mean)
        np.testing.assert_array_equal(got.covariance, want.covariance)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("index", [0, 1, 2])
def test_target_follower_non_finite_measurement_is_no_detection(bad, index):
    """Before: ``ValueError: array must not contain infs or NaNs`` from the estimator."""
    estimates, _ = run(TARGET_FOLLOWER, with_values(TARGET_PX, index, bad))
    expected, _ = run(TARGET_FOLLOWER, target_not_seen)
    for got, want in zip(estimates, expected, strict=True):
        assert got.measurement is None or np.all(np.isfinite(got.measurement))
        np.testing.assert_array_equal(got.mean, want.mean)
        np.testing.assert_array_equal(got.covariance, want.covariance)
        assert got.measurement_used == want.measurement_used


@pytest.mark.parametrize("env_id", [BALL_TABLE, TARGET_FOLLOWER])
@pytest.mark.parametrize(
    ("make_image", "given"),
    [
        (lambda image: image[..., 0], r"shape \(240, 320\) and dtype uint8"),  # grayscale
        (lambda image: image[::2, ::2], r"shape \(120, 160, 3\) and dtype uint8"),  # half size
        (lambda image: image.astype(np.float32), r"shape \(240, 320, 3\) and dtype float32"),
        (lambda image: image[..., :2], r"shape \(240, 320, 2\) and dtype uint8"),
        (lambda image: image.tolist(), r"shape None and dtype list"),
    ],
)
def test_frames_of_the_wrong_shape_or_dtype_raise(env_id, make_image, given):
    """Before: a grayscale frame crashed with cv2.error, a half-size one was taken (102 px
    of error for TargetFollower)."""
    env = gym.make(env_id, obs_mode="rgb").unwrapped
    try:
        pipeline = default_pipeline(env)
        zero = np.zeros(env.action_space.shape, np.float32)
        obs, info = env.reset(seed=0)
        pipeline.observe(obs, info, None)
        obs, *_, info = env.step(zero)
        assert info["frames"]
        expected = r"shape \(240, 320, 3\) and dtype uint8, got " + given
        with pytest.raises(ValueError, match=expected):
            pipeline.observe(make_image(obs), info, zero)
        pipeline.observe(obs, info, zero)  # the right frame still passes
    finally:
        env.close()


@pytest.mark.parametrize("env_id", [BALL_TABLE, TARGET_FOLLOWER])
def test_frame_size_comes_from_the_env(env_id):
    """Another image size in the env config: its frames pass, the default size raises."""
    env = gym.make(env_id, obs_mode="rgb", image_width_px=160, image_height_px=120).unwrapped
    try:
        pipeline = default_pipeline(env)
        zero = np.zeros(env.action_space.shape, np.float32)
        obs, info = env.reset(seed=0)
        pipeline.observe(obs, info, None)
        obs, *_, info = env.step(zero)
        assert obs.shape == (120, 160, 3)
        pipeline.observe(obs, info, zero)
        with pytest.raises(ValueError, match=r"\(120, 160, 3\).*got shape \(240, 320, 3\)"):
            pipeline.observe(np.zeros((240, 320, 3), np.uint8), info, zero)
    finally:
        env.close()
