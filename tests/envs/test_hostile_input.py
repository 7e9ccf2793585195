"""Bad input is refused with a ValueError that names what was wrong and what is allowed,
before it reaches PyBullet, and leaves the world as it was: config values (NumPy scalars
are good numbers), actions that are not real numbers, reset options of every env."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium.utils.env_checker import data_equivalence

import observer_gym.envs
from observer_gym.envs.ball_table import BallTableConfig

ENV_IDS = observer_gym.envs.ENV_IDS


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("image_width_px", np.int64(160)),
        ("image_width_px", np.int32(160)),
        ("physics_substeps", np.uint8(4)),
        ("hfov_deg", np.float32(75.0)),
        ("max_tilt_rad", np.float64(0.05)),
        ("push_rate_hz", np.int64(1)),
    ],
)
def test_numpy_scalars_are_numbers_and_are_stored_as_python_numbers(name, value):
    config = BallTableConfig.from_kwargs(**{name: value})
    stored = getattr(config, name)
    assert stored == value
    assert type(stored) in (int, float)


@pytest.mark.parametrize("name", ["image_width_px", "hfov_deg", "push_rate_hz"])
def test_ints_too_big_for_a_float_are_a_value_error(name):
    with pytest.raises(ValueError, match=rf"^{name}=1000.*allowed: \["):
        BallTableConfig.from_kwargs(**{name: 10**400})


# Each bad action, made at an env's action size n.
BAD_ACTIONS = {
    "complex": lambda n: np.array([0.05 + 1j] + [0.0] * (n - 1)),
    "complex scalars": lambda n: [0.05 + 0j] + [0.0] * (n - 1),
    "strings": lambda n: ["0.05"] + ["0"] * (n - 1),
    "masked": lambda n: np.ma.masked_array(np.zeros(n), mask=[True] + [False] * (n - 1)),
    "huge int": lambda n: [10**400] + [0] * (n - 1),
    "None entry": lambda n: [None] + [0.0] * (n - 1),
    "ragged": lambda n: [[0.1]] + [[0.2, 0.3]] * (n - 1),
    "bool": lambda n: np.array([True] + [False] * (n - 1)),
}


@pytest.mark.parametrize("case", list(BAD_ACTIONS))
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_actions_that_are_not_real_numbers_are_refused(make_env, env_id, case):
    env = make_env(env_id, obs_mode="state")
    fresh = make_env(env_id, obs_mode="state")
    env.reset(seed=0)
    fresh.reset(seed=0)
    with pytest.raises(ValueError, match="action must"):
        env.step(BAD_ACTIONS[case](env.action_space.shape[0]))
    good = np.zeros(env.action_space.shape, np.float32)
    assert data_equivalence(env.step(good), fresh.step(good))  # the world is as it was


RESET_CASES = {
    "observer_gym/BallTable-v0": [
        (5, "reset options must be a dict"),
        ("ball_pos_table_m", "reset options must be a dict"),
        ({"ball_pos_table_m": "0.1, 0"}, "ball_pos_table_m must be 2 finite numbers"),
        ({"ball_vel_table_mps": [0.1, 1j]}, "ball_vel_table_mps must be 2 finite numbers"),
        ({"ball_vel_table_mps": [10**400, 0]}, "ball_vel_table_mps must be 2 finite numbers"),
    ],
    "observer_gym/BallCatcher-v1": [
        (5, "reset options must be a dict"),
        ({"thrown": None}, r"unknown reset options \['thrown'\]"),
    ],
    "observer_gym/TargetFollower-v0": [
        ([1, 2], "reset options must be a dict"),
        ({"target_pos_world_m": [1e30, 0, 1]}, "target_pos_world_m must be 3 finite numbers"),
        ({"target_pos_world_m": "here"}, "target_pos_world_m must be 3 finite numbers"),
        ({"occlusions_s": [float("nan")]}, "occlusions_s must be 1 finite numbers"),
        ({"occlusions_s": [-1.0]}, "occlusions_s must be times >= 0"),
        ({"occlusions_s": 5}, "occlusions_s must be a sequence"),
        ({"tilt_rad": "abc"}, r"tilt_rad='abc' must be a number; allowed: \[-0.35, 1.2\]"),
        ({"tilt_rad": None}, "tilt_rad=None must be a number"),
        ({"tilt_rad": 2.0}, r"tilt_rad=2.0 is out of range; allowed: \[-0.35, 1.2\]"),
    ],
}


@pytest.mark.parametrize(
    ("env_id", "options", "pattern"),
    [(env_id, o, p) for env_id, cases in RESET_CASES.items() for o, p in cases],
)
def test_bad_reset_options_name_the_option_and_what_is_allowed(make_env, env_id, options, pattern):
    env = make_env(env_id, obs_mode="state")
    with pytest.raises(ValueError, match=pattern):
        env.reset(seed=0, options=options)


def test_good_reset_options_take_numpy_values(make_env):
    env = make_env("observer_gym/TargetFollower-v0", obs_mode="state")
    _, info = env.reset(
        seed=0,
        options={"tilt_rad": np.float32(0.1), "target_pos_world_m": np.array([2.0, 0.0, 1.5])},
    )
    assert info["state"][9] == pytest.approx(0.1, abs=1e-6)  # tilt
    np.testing.assert_allclose(info["target_pos_world"], [2.0, 0.0, 1.5])
