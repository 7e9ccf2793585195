"""The defects the fuzz suite found, each pinned by its reproducer."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import data_equivalence

from observer_gym.controllers import make_controller
from observer_gym.envs.ball_table import BallTableConfig
from observer_gym.estimation import default_pipeline


@pytest.mark.parametrize("value", [np.array([0, 0], np.int8), np.array(["fixed"]), ["fixed"]])
def test_an_array_for_a_choice_field_is_refused_naming_the_field(value):
    """Before: np.array([0, 0]) raised numpy's unnamed "truth value of an array ... is
    ambiguous" ValueError, and np.array(["fixed"]) was accepted and stored as an array."""
    with pytest.raises(ValueError, match=r"^calib_error_draw=.* is not allowed; choose one of"):
        BallTableConfig.from_kwargs(calib_error_draw=value)


def test_a_numpy_string_choice_is_stored_as_the_choice():
    config = BallTableConfig.from_kwargs(calib_error_draw=np.str_("fixed"))
    assert type(config.calib_error_draw) is str and config.calib_error_draw == "fixed"


def test_unknown_reset_options_of_mixed_key_types_are_named(make_env):
    """Before: TypeError from sorting the unknown keys (int < str)."""
    env = make_env("observer_gym/BallCatcher-v1", obs_mode="state")
    with pytest.raises(ValueError, match=r"unknown reset options \['x', 0\]; allowed: throw"):
        env.reset(seed=0, options={"x": None, 0: None})


@pytest.mark.parametrize(
    "throw",
    [
        (["1", "0", "0.5"], [0, 0, 1]),  # strings
        (np.array([1 + 1j, 0, 0.5]), [0, 0, 1]),  # complex: the imaginary part was dropped
        (np.array([True, False, True]), [0, 0, 1]),  # bools
        np.ma.masked_array([[1.0, 0.0, 0.5], [0.0, 0.0, 1.0]], mask=[[1, 0, 0], [0, 0, 0]]),
    ],
)
def test_a_throw_of_anything_but_real_numbers_is_refused(make_env, throw):
    """Before: each was taken (``np.asarray(v, dtype=float)``)."""
    env = make_env("observer_gym/BallCatcher-v1", obs_mode="state")
    with pytest.raises(ValueError, match=r"reset option throw must be .* two 3-vectors"):
        env.reset(seed=0, options={"throw": throw})


@pytest.mark.parametrize(
    ("env_id", "options"),
    [
        ("observer_gym/BallTable-v0", {"ball_vel_table_mps": [np.nan, 0.0]}),
        ("observer_gym/BallCatcher-v1", {"throw": (np.zeros(3), [0.0, 0.0, 123.0])}),
        ("observer_gym/TargetFollower-v0", {"occlusions_s": [-1.0]}),
        ("observer_gym/TargetFollower-v0", {"tilt_rad": "up"}),
    ],
)
def test_a_refused_reset_changes_nothing(make_env, env_id, options):
    """Before: the option's value was checked after the world was cleared and rebuilt
    (and np_random reseeded), so the episode could not go on after the ValueError."""
    env, ref = make_env(env_id, obs_mode="state"), make_env(env_id, obs_mode="state")
    zero = np.zeros(env.action_space.shape, np.float32)
    env.reset(seed=1)
    ref.reset(seed=1)
    env.step(zero)
    ref.step(zero)
    with pytest.raises(ValueError, match="reset option"):
        env.reset(seed=2, options=options)
    for _ in range(3):
        assert data_equivalence(env.step(zero), ref.step(zero))


def test_ragged_occlusions_are_refused_naming_the_option(make_env):
    """Before: numpy's unnamed 'inhomogeneous shape' ValueError."""
    env = make_env("observer_gym/TargetFollower-v0", obs_mode="state")
    with pytest.raises(ValueError, match="reset option occlusions_s must be a sequence"):
        env.reset(seed=0, options={"occlusions_s": [[1.0], [1.0, 2.0]]})


def _first_observation(env_id, mode="measurements"):
    env = gym.make(env_id, obs_mode=mode, image_width_px=64, image_height_px=48).unwrapped
    zero = np.zeros(env.action_space.shape, np.float32)
    env.reset(seed=0)
    obs, *_, info = env.step(zero)
    return env, obs, info, zero


@pytest.mark.parametrize(
    ("env_id", "change"),
    [
        ("observer_gym/BallTable-v0", lambda obs: None),  # TypeError
        ("observer_gym/BallTable-v0", lambda obs: {k: v for k, v in obs.items() if k != "ball_px"}),
        ("observer_gym/BallTable-v0", lambda obs: {**obs, "table_corners_px": np.zeros(3)}),
        ("observer_gym/TargetFollower-v0", lambda obs: [1.0, 2.0]),  # TypeError
        ("observer_gym/TargetFollower-v0", lambda obs: {"detected": np.ones(1, np.int8)}),
        ("observer_gym/TargetFollower-v0", lambda obs: {**obs, "target_px": ["1", "2", "3"]}),
    ],
)
def test_a_bad_measurement_is_a_value_error(env_id, change):
    """Before: TypeError, KeyError, or numpy's unnamed reshape ValueError; strings parsed."""
    env, obs, info, zero = _first_observation(env_id)
    try:
        pipeline = default_pipeline(env)
        with pytest.raises(ValueError, match=r"Observer: .*measurement"):
            pipeline.observe(change(obs), info, zero)
        pipeline.observe(obs, info, zero)  # the real one still passes
    finally:
        env.close()


@pytest.mark.parametrize(
    ("mode", "key", "value"),
    [
        ("measurements", "uv_px", np.zeros((0, 4, 1))),  # IndexError before
        ("measurements", "uv_px", np.array([1 + 1j, 2.0])),  # the imaginary part was dropped
        ("measurements", "uv_px", None),  # missing: KeyError before
        ("rgb", "image", None),  # missing: KeyError before
    ],
)
def test_a_bad_ball_catcher_frame_is_a_value_error(mode, key, value):
    env, _, info, zero = _first_observation("observer_gym/BallCatcher-v1", mode)
    try:
        frames = [dict(f) for f in info["frames"]]
        if value is None:
            del frames[0][key]
        else:
            frames[0][key] = value
        with pytest.raises(ValueError, match=r"BallCatcherObserver: .*(uv_px|frame of camera)"):
            default_pipeline(env).observe(None, {**info, "frames": frames}, zero)
    finally:
        env.close()


def test_a_ball_catcher_pixel_no_camera_reports_is_no_detection():
    """Before: uv = (u, 1e308) overflowed the viewline filter's update (LinAlgError: S is
    not positive definite)."""
    env, _, info, zero = _first_observation("observer_gym/BallCatcher-v1")
    try:
        pipeline = default_pipeline(env)
        frames = [dict(f) for f in info["frames"]]
        for frame in frames:
            frame["uv_px"] = np.array([10.0, 1e308])
        estimate = pipeline.observe(None, {**info, "frames": frames}, zero)
        assert np.all(np.isfinite(estimate.mean)) and not estimate.measurement_used
    finally:
        env.close()


@pytest.mark.parametrize(
    "make_obs",
    [
        lambda n: np.full(n, 0.1 + 1j),  # the imaginary part was dropped
        lambda n: np.zeros(n, "datetime64[s]"),
        lambda n: [str(0.0)] * n,  # parsed
        lambda n: np.ma.masked_array(np.zeros(n), mask=True),
        lambda n: [10**400] + [0.0] * (n - 1),  # OverflowError before
    ],
)
def test_predict_refuses_observations_that_are_not_real_numbers(make_env, make_obs):
    env = make_env("observer_gym/BallTable-v0", obs_mode="state")
    controller = make_controller("lqr", env)
    with pytest.raises(ValueError, match="predict: observation must be an array of numbers"):
        controller.predict(make_obs(env.unwrapped.state_space.shape[0]))


@pytest.mark.parametrize(("omega", "damping"), [(1e200, 0.9), (1e160, 1e160)])
def test_pid_gains_beyond_float_name_omega_and_damping(make_env, omega, damping):
    """Before: OverflowError from omega_radps**2 (1e200), or a ValueError naming only the
    derived gain kd (1e160, 1e160)."""
    env = make_env("observer_gym/BallTable-v0", obs_mode="state")
    with pytest.raises(ValueError, match=r"= inf, must be finite .* omega_radps = .* damping ="):
        make_controller("pid", env, omega_radps=omega, damping=damping)


@pytest.mark.parametrize("index", [0, 1, 2])
def test_a_ball_table_pixel_no_camera_reports_is_no_detection(index):
    """Before: ball_px with 1e308 raised ZeroDivisionError in the geometry stage."""
    env, obs, info, zero = _first_observation("observer_gym/BallTable-v0")
    try:
        pipeline, reference = default_pipeline(env), default_pipeline(env)
        ball = np.array(obs["ball_px"], dtype=float)
        ball[index] = 1e308
        nan = ball.copy()
        nan[index] = np.nan
        got = pipeline.observe({**obs, "ball_px": ball}, info, zero)
        want = reference.observe({**obs, "ball_px": nan}, info, zero)
        np.testing.assert_array_equal(got.mean, want.mean)
        assert np.all(np.isfinite(got.mean))
    finally:
        env.close()
