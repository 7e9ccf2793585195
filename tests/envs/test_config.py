"""BallTable-v0's configuration: bad options fail early with a message that says what is
wrong and what is allowed; good options take effect; bad reset options are rejected."""

from __future__ import annotations

import dataclasses
import math
import re

import gymnasium as gym
import numpy as np
import pytest

import observer_gym.envs  # noqa: F401  (registers the envs)
import observer_gym.envs.core as env_core
from observer_gym.envs.ball_table import geometry as geo
from observer_gym.envs.ball_table.config import BallTableConfig

ENV_ID = "observer_gym/BallTable-v0"

# (field, bad value, text naming what is allowed), in envs/config.py's message format.
BAD_VALUES = [
    ("obs_mode", "pixels", "choose one of ['rgb', 'state', 'measurements']"),
    ("image_width_px", 10, "out of range; allowed: [32, 1280]"),
    ("hfov_deg", 179.0, "out of range; allowed: [20.0, 120.0]"),
    ("max_tilt_rad", -0.1, "out of range; allowed: [0.01, 0.3]"),
    ("frame_drop_prob", 1.5, "out of range; allowed: [0.0, 1.0]"),
    ("physics_substeps", 2.5, "must be an integer; allowed: [1, 50]"),
    ("start_radius_m", float("nan"), "must be finite; allowed: [0.0, 0.125]"),
    ("camera_motion", "spin", "choose one of ['fixed', 'head']"),
    ("push_rate_hz", True, "must be a number; allowed: [0.0, 10.0]"),
]
BAD_IDS = [f"{name}={value!r}" for name, value, _ in BAD_VALUES]


def _check_message(excinfo, name, value, allowed) -> None:
    message = str(excinfo.value)
    assert message.startswith(f"{name}={value!r} "), message  # the field and the bad value
    assert allowed in message, message


@pytest.mark.parametrize(("name", "value", "allowed"), BAD_VALUES, ids=BAD_IDS)
def test_bad_value_through_gym_make(name, value, allowed):
    with pytest.raises(ValueError, match=re.escape(name)) as excinfo:
        gym.make(ENV_ID, **{name: value})
    _check_message(excinfo, name, value, allowed)


@pytest.mark.parametrize(("name", "value", "allowed"), BAD_VALUES, ids=BAD_IDS)
def test_bad_value_through_config(name, value, allowed):
    with pytest.raises(ValueError, match=re.escape(allowed)) as excinfo:
        BallTableConfig(**{name: value})
    _check_message(excinfo, name, value, allowed)
    with pytest.raises(ValueError, match=re.escape(allowed)) as excinfo:
        BallTableConfig.from_kwargs(**{name: value})
    _check_message(excinfo, name, value, allowed)


def test_range_bounds_are_inclusive():
    cfg = BallTableConfig(image_width_px=32, hfov_deg=120.0, frame_drop_prob=1.0)
    assert (cfg.image_width_px, cfg.hfov_deg, cfg.frame_drop_prob) == (32, 120.0, 1.0)
    with pytest.raises(ValueError, match=r"image_width_px=31 is out of range"):
        BallTableConfig(image_width_px=31)


def test_unknown_keyword_suggests_the_close_option():
    with pytest.raises(ValueError, match=r"no option 'obs_mod'\. Did you mean 'obs_mode'\?"):
        gym.make(ENV_ID, obs_mod="state")
    with pytest.raises(ValueError, match=r"Did you mean 'obs_mode'\?"):
        BallTableConfig.from_kwargs(obs_mod="state")


# Gymnasium's make warns about the unknown mode before the env rejects it.
IGNORE_GYM_RENDER_MODE_WARNING = pytest.mark.filterwarnings(
    "ignore:.*render_mode='rgb_arrays'.*:UserWarning"
)


@IGNORE_GYM_RENDER_MODE_WARNING
def test_bad_render_mode():
    with pytest.raises(ValueError, match=r"render_mode='rgb_arrays' is not supported"):
        gym.make(ENV_ID, render_mode="rgb_arrays", obs_mode="state")


@pytest.fixture
def simulation_calls(monkeypatch):
    """Replace the env's Simulation with a recorder that still builds the real one."""
    calls = []
    real_simulation = env_core.Simulation

    def recording_simulation(*args, **kwargs):
        calls.append((args, kwargs))
        return real_simulation(*args, **kwargs)

    monkeypatch.setattr(env_core, "Simulation", recording_simulation)
    return calls


@IGNORE_GYM_RENDER_MODE_WARNING
@pytest.mark.parametrize(
    "kwargs",
    [
        {"obs_mode": "pixels"},
        {"physics_substeps": 2.5},
        {"obs_mod": "state"},
        {"render_mode": "rgb_arrays"},
    ],
    ids=["bad value", "bad type", "unknown option", "bad render_mode"],
)
def test_errors_are_raised_before_any_client_is_created(simulation_calls, kwargs):
    with pytest.raises(ValueError):
        gym.make(ENV_ID, **kwargs)
    assert simulation_calls == []


def test_the_simulation_recorder_sees_a_valid_env(simulation_calls, make_env):
    # The counterpart of the test above: the patch really intercepts the env's world.
    make_env(ENV_ID, obs_mode="state")
    assert len(simulation_calls) == 1


def test_describe_lists_every_field_exactly_once():
    lines = BallTableConfig.describe().splitlines()
    names = [f.name for f in dataclasses.fields(BallTableConfig)]
    assert len(lines) == len(names)
    described = [line.split(" = ", 1)[0] for line in lines]
    assert sorted(described) == sorted(names)
    for f in dataclasses.fields(BallTableConfig):
        line = lines[described.index(f.name)]
        assert line.startswith(f"{f.name} = {f.default!r} ("), line
        assert line.endswith(f.metadata["doc"]), line


def test_valid_non_default_camera_takes_effect(make_env):
    env = make_env(ENV_ID, obs_mode="rgb", image_width_px=160, image_height_px=120, hfov_deg=60)
    assert env.observation_space.shape == (120, 160, 3)
    obs, info = env.reset(seed=0)
    assert obs.shape == (120, 160, 3)
    assert obs.dtype == np.uint8
    fx = 80.0 / math.tan(math.radians(30.0))
    K = info["camera"]["K"]
    assert abs(K[0, 0] - fx) < 1e-9
    assert abs(K[1, 1] - fx) < 1e-9
    assert (K[0, 2], K[1, 2]) == (80.0, 60.0)
    assert tuple(info["camera"]["image_size_px"]) == (160, 120)
    obs, *_, info = env.step(np.zeros(2, dtype=np.float32))
    assert obs.shape == (120, 160, 3)
    assert abs(info["camera"]["K"][0, 0] - fx) < 1e-9


@pytest.mark.parametrize(
    ("options", "pattern"),
    [
        ({"ball_position": (0.0, 0.0)}, r"unknown reset options \['ball_position'\]"),
        ({"ball_pos_table_m": (geo.BALL_TRAVEL_M + 1e-3, 0.0)}, r"ball_pos_table_m must be"),
        ({"ball_pos_table_m": (0.0, -0.13)}, r"ball_pos_table_m must be"),
        ({"ball_pos_table_m": (0.0, 0.0, 0.0)}, r"ball_pos_table_m must be 2 finite"),
        ({"ball_vel_table_mps": (float("nan"), 0.0)}, r"ball_vel_table_mps must be 2 finite"),
        ({"ball_vel_table_mps": (0.0, float("inf"))}, r"ball_vel_table_mps must be 2 finite"),
    ],
    ids=["unknown key", "x too far", "y too far", "3 numbers", "nan velocity", "inf velocity"],
)
def test_bad_reset_options(make_env, options, pattern):
    env = make_env(ENV_ID, obs_mode="state")
    with pytest.raises(ValueError, match=pattern):
        env.reset(seed=0, options=options)


def test_reset_options_at_the_bound_are_accepted(make_env):
    env = make_env(ENV_ID, obs_mode="state")
    assert geo.BALL_TRAVEL_M == pytest.approx(0.125)
    _, info = env.reset(
        seed=0,
        options={"ball_pos_table_m": (geo.BALL_TRAVEL_M, -0.05), "ball_vel_table_mps": (0, 0)},
    )
    np.testing.assert_allclose(info["state"][:4], [geo.BALL_TRAVEL_M, -0.05, 0, 0], atol=1e-6)
