"""Properties every registered env keeps, for every obs_mode (Gymnasium's and
dm_control's suite tests are the model): API conformance, determinism, randomised
starts, clean action checking."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from gymnasium.wrappers import RescaleAction
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import observer_gym.envs

# every registered system's env (the toy of tests/toy_system too)
ENV_IDS = tuple(system.env_id for system in observer_gym.envs.SYSTEMS)
OBS_MODES = ("rgb", "state", "measurements")
CASES = [(env_id, mode) for env_id in ENV_IDS for mode in OBS_MODES]
# SB3 recommends a [-1, 1] action space; our envs keep physical units (radians) and the
# training code rescales them, so this one warning is expected on the raw env.
SB3_RESCALE_HINT = "symmetric and normalized Box action space"
SLOW_RGB = {("observer_gym/BallTable-v0", "rgb"), ("observer_gym/BallCatcher-v1", "rgb")}


def knobs(env_id: str):
    """The options the env declares for the suite (``suite_knobs``, envs/suite_knobs.py)."""
    return observer_gym.envs.system_for_id(env_id).env_class().suite_knobs


def _warnings_of(check, env) -> list[str]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check(env)
    return [str(w.message) for w in caught]


@pytest.mark.parametrize(("env_id", "obs_mode"), CASES)
def test_gymnasium_check_env_passes_without_warnings(make_env, env_id, obs_mode):
    env = make_env(env_id, obs_mode=obs_mode, render_mode="rgb_array")
    assert _warnings_of(lambda e: gym_check_env(e.unwrapped), env) == []


@pytest.mark.parametrize(("env_id", "obs_mode"), CASES)
def test_sb3_check_env_passes(make_env, env_id, obs_mode):
    env = make_env(env_id, obs_mode=obs_mode)
    raw = _warnings_of(lambda e: sb3_check_env(e.unwrapped), env)
    if np.array_equal(env.action_space.high, np.ones(env.action_space.shape)):
        assert raw == []  # already in [-1, 1]
    else:
        assert len(raw) == 1 and SB3_RESCALE_HINT in raw[0], raw
    one = np.ones(env.action_space.shape, np.float32)
    rescaled = _warnings_of(lambda e: sb3_check_env(RescaleAction(e.unwrapped, -one, one)), env)
    assert rescaled == []


def _rollout(env: gym.Env, seed: int, steps: int):
    obs, info = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    trace = [(obs, info["state"])]
    for _ in range(steps):
        action = rng.uniform(env.action_space.low, env.action_space.high).astype(np.float32)
        obs, reward, terminated, truncated, info = env.step(action)
        trace.append((obs, info["state"], reward))
        if terminated or truncated:
            obs, info = env.reset()
            trace.append((obs, info["state"]))
    return trace


def _assert_same(trace_a, trace_b):
    assert len(trace_a) == len(trace_b)
    for a, b in zip(trace_a, trace_b, strict=True):
        for x, y in zip(a, b, strict=True):
            if isinstance(x, dict):
                assert x.keys() == y.keys()
                for key in x:
                    np.testing.assert_array_equal(x[key], y[key])
            else:
                np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize(
    ("env_id", "obs_mode"),
    [  # 400 rendered steps of BallTable and BallCatcher (4 s and 2.5 s idle): slow
        pytest.param(*case, marks=pytest.mark.slow) if case in SLOW_RGB else case for case in CASES
    ],
)
def test_same_seed_same_observations_for_200_steps(make_env, env_id, obs_mode):
    kwargs = {"obs_mode": obs_mode, **knobs(env_id).disturbed}
    if obs_mode == "measurements":
        kwargs.update(knobs(env_id).measurement_noise)
    trace_a = _rollout(make_env(env_id, **kwargs), seed=7, steps=200)
    trace_b = _rollout(make_env(env_id, **kwargs), seed=7, steps=200)
    _assert_same(trace_a, trace_b)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_reset_after_use_equals_fresh_reset(make_env, env_id):
    used = make_env(env_id, obs_mode="rgb")
    _rollout(used, seed=1, steps=60)
    fresh = make_env(env_id, obs_mode="rgb")
    _assert_same(_rollout(used, seed=3, steps=30), _rollout(fresh, seed=3, steps=30))


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_starts_are_randomised_by_the_seed(make_env, env_id):
    env = make_env(env_id, obs_mode="state")
    starts = np.array([env.reset(seed=seed)[1]["state"] for seed in range(10)])
    assert len({tuple(s) for s in starts.round(6)}) == 10
    assert np.ptp(starts, axis=0).max() > 0.01


def _bad_actions(n: int) -> list:
    """Actions that must raise for an env whose action space is a Box of shape (n,)."""
    zeros = [0.0] * n
    return [
        [np.nan, *zeros[1:]],
        [*zeros[:-1], np.inf],
        [-np.inf, *zeros[1:]],
        zeros[:-1],  # too short
        [*zeros, 0.0],  # too long
        [zeros],  # nested
        "up",
    ]


@pytest.mark.parametrize("env_id", ENV_IDS)
@pytest.mark.parametrize("case", range(7))
def test_bad_actions_raise_before_reaching_the_simulator(make_env, env_id, case):
    env = make_env(env_id, obs_mode="state")
    fresh = make_env(env_id, obs_mode="state")
    bad_action = _bad_actions(env.action_space.shape[0])[case]
    env.reset(seed=0)
    fresh.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        env.step(bad_action)
    # The world is as it was: the next valid step matches a fresh env's, and is finite.
    zero = np.zeros(env.action_space.shape, np.float32)
    obs, _, _, _, info = env.step(zero)
    obs_fresh, _, _, _, info_fresh = fresh.step(zero)
    np.testing.assert_array_equal(info["state"], info_fresh["state"])
    np.testing.assert_array_equal(obs, obs_fresh)
    assert np.all(np.isfinite(obs))


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_out_of_range_actions_are_clipped(make_env, env_id):
    big, edge = make_env(env_id, obs_mode="state"), make_env(env_id, obs_mode="state")
    high = edge.action_space.high
    for env in (big, edge):
        env.reset(seed=0)
    for _ in range(20):
        obs_big, *_ = big.step(10.0 * high)
        obs_edge, *_ = edge.step(high)
    np.testing.assert_array_equal(obs_big, obs_edge)


def _world_trace(env: gym.Env, seed: int, steps: int) -> list[tuple]:
    """Per step: the ground truth, the time, and which frames were captured when (the
    disturbances: pushes, target motion and occluders act on the state; drops and jitter on
    the frames); reset without a seed after an episode ends."""

    def world(info, done=False):
        frames = [(f["camera_id"], f["capture_time_s"]) for f in info["frames"]]
        return info["state"], info["time_s"], np.array(frames).reshape(-1, 2), done

    _, info = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    trace = [world(info)]
    for _ in range(steps):
        action = 0.3 * rng.uniform(env.action_space.low, env.action_space.high)
        _, _, terminated, truncated, info = env.step(action.astype(np.float32))
        trace.append(world(info, terminated or truncated))
        if terminated or truncated:
            _, info = env.reset()
            trace.append(world(info))
    return trace


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_disturbances_are_the_same_in_every_obs_mode(make_env, env_id):
    # observer-gym compare runs every (observer, controller) pair on the same seeds: the
    # world (ground truth, frame drops and capture times) must not depend on the obs_mode
    # or on its sensor noise.
    suite = knobs(env_id)
    kwargs = {**suite.disturbed, **suite.measurement_noise, **suite.paired}
    traces = {
        mode: _world_trace(make_env(env_id, obs_mode=mode, **kwargs), seed=3, steps=150)
        for mode in OBS_MODES
    }
    reference = traces["state"]
    assert sum(len(frames) == 0 for _, _, frames, _ in reference) > 5  # drops happened
    for mode in ("measurements", "rgb"):
        assert len(traces[mode]) == len(reference), mode
        for i, (a, b) in enumerate(zip(reference, traces[mode], strict=True)):
            for x, y in zip(a, b, strict=True):
                np.testing.assert_array_equal(x, y, err_msg=f"{mode}, entry {i} of the trace")


def test_later_resets_draw_fresh_sensor_noise(make_env):
    # The sensor noise has its own stream, derived from the reset seed: reset(seed=s)
    # repeats it, a reset without a seed continues with new noise.
    env = make_env("observer_gym/BallTable-v0", obs_mode="measurements", measurement_noise_px=1.0)
    start = {"ball_pos_table_m": (0.02, -0.01), "ball_vel_table_mps": (0.0, 0.0)}
    first, _ = env.reset(seed=5, options=start)
    again, _ = env.reset(seed=5, options=start)
    later, _ = env.reset(options=start)
    np.testing.assert_array_equal(first["ball_px"], again["ball_px"])
    assert np.all(first["ball_px"] != later["ball_px"])


@pytest.mark.parametrize("obs_mode", ("rgb", "measurements"))
@pytest.mark.parametrize("env_id", ["observer_gym/BallTable-v0", "observer_gym/TargetFollower-v0"])
def test_a_repeated_frame_is_a_copy(make_env, env_id, obs_mode):
    # Every frame after the first is dropped, so each step repeats the reset's frame: equal
    # observations, but not one object, so changing one in place cannot change the next.
    env = make_env(env_id, obs_mode=obs_mode, frame_drop_prob=1.0)
    first, _ = env.reset(seed=0)
    action = np.zeros(env.action_space.shape, np.float32)
    second, _, _, _, info = env.step(action)
    third, *_ = env.step(action)
    assert info["frames"] == []
    for a, b in ((first, second), (second, third)):
        assert a is not b
        arrays_a = a.values() if isinstance(a, dict) else [a]
        arrays_b = b.values() if isinstance(b, dict) else [b]
        for x, y in zip(arrays_a, arrays_b, strict=True):
            np.testing.assert_array_equal(x, y)
            assert not np.shares_memory(x, y)


@pytest.mark.parametrize("env_id", ["observer_gym/BallTable-v0", "observer_gym/TargetFollower-v0"])
def test_render_in_rgb_mode_gives_a_copy_of_the_last_frame(make_env, env_id):
    # In rgb mode render() gives the last camera frame, not a new render; drawing on it
    # (an overlay) must change neither a later render nor the frame a dropped one repeats.
    env = make_env(env_id, obs_mode="rgb", render_mode="rgb_array", frame_drop_prob=1.0)
    obs, _ = env.reset(seed=0)
    frame = env.render()
    np.testing.assert_array_equal(frame, obs)
    frame[:] = 0
    np.testing.assert_array_equal(env.render(), obs)
    repeated, *_ = env.step(np.zeros(env.action_space.shape, np.float32))
    np.testing.assert_array_equal(repeated, obs)
