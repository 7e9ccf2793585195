"""Copies and closed envs: a pickled or deep-copied env is an independent env with its own
PyBullet client that steps on exactly as the original, whenever it is taken; ``reset``
after ``close`` works (SB3's ``check_env`` with the render check does that).
The bound on what a copy keeps: tests/envs/test_copy_history.py; closed envs:
tests/envs/test_closed_env.py."""

from __future__ import annotations

import copy
import pickle
import warnings

import numpy as np
import pytest
from gymnasium.utils.env_checker import data_equivalence
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import observer_gym.envs

# every registered system's env (the toy of tests/toy_system too)
ENV_IDS = tuple(system.env_id for system in observer_gym.envs.SYSTEMS)
OBS_MODES = ("rgb", "state", "measurements")
CASES = [(env_id, mode) for env_id in ENV_IDS for mode in OBS_MODES]
SMALL = {"image_width_px": 80, "image_height_px": 60}


def _disturbed(env_id: str) -> dict:
    """Disturbances and sensor noise on (the env's ``suite_knobs``), so that a copy must
    also carry the generators' states."""
    suite = observer_gym.envs.system_for_id(env_id).env_class().suite_knobs
    return {**suite.disturbed, **suite.measurement_noise}


def _actions(env, n: int, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    space = env.action_space
    # float64, as a controller or an agent gives them: a copy must replay them exactly, not
    # rounded to the space's float32
    return [rng.uniform(space.low, space.high) * 0.3 for _ in range(n)]


def _client(env) -> int:
    return env.unwrapped.sim.client_id


@pytest.mark.parametrize(("env_id", "obs_mode"), CASES)
def test_pickle_env(make_env, env_id, obs_mode):
    # Gymnasium's own test_pickle_env, on a fresh (never reset) env.
    env = make_env(env_id, obs_mode=obs_mode, **SMALL)
    pickled_env = pickle.loads(pickle.dumps(env))
    try:
        assert data_equivalence(env.reset(), pickled_env.reset())
        action = env.action_space.sample()
        assert data_equivalence(env.step(action), pickled_env.step(action))
    finally:
        env.close()
        pickled_env.close()


@pytest.mark.parametrize("copier", [copy.deepcopy, lambda e: pickle.loads(pickle.dumps(e))])
@pytest.mark.parametrize(("env_id", "obs_mode"), CASES)
def test_a_copy_mid_episode_steps_on_like_the_original_and_a_fresh_env(
    make_env, env_id, obs_mode, copier
):
    options = {"obs_mode": obs_mode, **SMALL, **_disturbed(env_id)}
    env = make_env(env_id, **options)
    fresh = make_env(env_id, **options)
    actions = _actions(env, 8)
    env.reset(seed=4)
    fresh.reset(seed=4)
    for a in actions[:4]:
        env.step(a)
        fresh.step(a)
    twin = copier(env)
    try:
        assert _client(twin) != _client(env)
        for a in actions[4:]:
            expected = fresh.step(a)
            assert data_equivalence(env.step(a), expected)
            assert data_equivalence(twin.step(a), expected)
        # Closing the copy leaves the original running, and the other way round.
        twin.close()
        assert data_equivalence(env.step(actions[0]), fresh.step(actions[0]))
    finally:
        twin.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_reset_after_close_builds_a_new_world(make_env, env_id):
    env = make_env(env_id, obs_mode="measurements")
    fresh = make_env(env_id, obs_mode="measurements")
    env.reset(seed=1)
    env.step(env.action_space.sample())
    env.close()
    assert data_equivalence(env.reset(seed=2), fresh.reset(seed=2))
    action = _actions(env, 1)[0]
    assert data_equivalence(env.step(action), fresh.step(action))


@pytest.mark.parametrize(("env_id", "obs_mode"), CASES)
def test_sb3_check_env_with_the_render_check(make_env, env_id, obs_mode):
    env = make_env(env_id, obs_mode=obs_mode, render_mode="rgb_array", **SMALL)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*symmetric and normalized Box action")
        sb3_check_env(env.unwrapped, skip_render_check=False)
    env.reset(seed=0)  # usable after check_env closed it


def test_step_before_reset_is_refused():
    from gymnasium.error import ResetNeeded

    from observer_gym.envs.ball_table import BallTableEnv

    env = BallTableEnv(obs_mode="state")
    try:
        with pytest.raises(ResetNeeded, match="reset"):
            env.step(np.zeros(2, np.float32))
    finally:
        env.close()


@pytest.mark.parametrize("copier", [copy.deepcopy, lambda e: pickle.loads(pickle.dumps(e))])
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_a_copy_right_after_reset_steps_on_like_the_original(make_env, env_id, copier):
    # The frames reset() delivered are delivered, not pending, in the copy too (a copy
    # with no step to replay once delivered the reset's frame again at its first step).
    options = {"obs_mode": "measurements", **_disturbed(env_id)}
    env = make_env(env_id, **options)
    env.reset(seed=2)
    twin = copier(env)
    try:
        for a in _actions(env, 3):
            assert data_equivalence(twin.step(a), env.step(a))
    finally:
        twin.close()


@pytest.mark.slow
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_copies_taken_at_every_step_continue_identically(make_env, env_id):
    # A copy at every step of a disturbed episode, each stepped on beside the original's
    # recorded steps. BallCatcher's zero actions leave the box in the ball's path: its
    # episode runs through the ball's contacts with the box to the catch or the miss.
    options = {"obs_mode": "measurements", **_disturbed(env_id)}
    reference = make_env(env_id, **options)
    env = make_env(env_id, **options)
    actions = _actions(env, 60, seed=3)
    if env_id == "observer_gym/BallCatcher-v1":
        actions = [np.zeros_like(a) for a in actions]
    reference.reset(seed=5)
    env.reset(seed=5)
    recorded = []
    for a in actions:
        recorded.append(copy.deepcopy(reference.step(a)))
        if recorded[-1][2]:  # terminated
            break
    if env_id == "observer_gym/BallCatcher-v1":
        assert not recorded[-1][4]["ball_in_flight"]  # the ball has touched the box
    for k in range(len(recorded)):
        twin = pickle.loads(pickle.dumps(env)) if k % 2 else copy.deepcopy(env)
        try:
            for j in range(k, min(k + 3, len(recorded))):
                assert data_equivalence(twin.step(actions[j]), recorded[j]), (k, j)
        finally:
            twin.close()
        env.step(actions[k])
