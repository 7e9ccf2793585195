"""What a copy keeps is bounded: an episode keeps its actions (what a copy replays) in one
array of the action's bytes per step, for at most ``copy_history_max_steps`` steps; past
that the episode goes on, the env holds no more, and a copy is refused with an error
naming the limit until the next reset (envs/core.py)."""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest
from gymnasium.utils.env_checker import data_equivalence

import observer_gym.envs

ENV_IDS = observer_gym.envs.ENV_IDS
CAP_STEPS = 40
# Pickle's framing of one array beside the per-step bytes (the header of a NumPy array).
PICKLE_SLACK_BYTES = 256


def _zero_action(env) -> np.ndarray:
    return np.zeros(env.action_space.shape, np.float64)  # as kept: float64


def _pickled_bytes(env) -> int:
    return len(pickle.dumps(env))


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_a_copy_costs_the_actions_bytes_per_step(make_env, env_id):
    env = make_env(env_id, obs_mode="state")
    env.reset(seed=0)
    action = _zero_action(env)
    env.step(action)
    one_step = _pickled_bytes(env)
    for _ in range(99):
        env.step(action)
    per_step = (_pickled_bytes(env) - one_step) / 99
    # A list of arrays cost about 110 B per step; the array of actions costs their bytes.
    assert per_step <= action.nbytes + 1, per_step


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_what_an_env_keeps_and_a_copy_carries_stays_bounded_as_the_episode_grows_tenfold(
    make_env, env_id
):
    env = make_env(env_id, obs_mode="state")
    env.unwrapped.copy_history_max_steps = CAP_STEPS
    env.reset(seed=0)
    action = _zero_action(env)
    fresh_bytes = _pickled_bytes(env)
    bound = fresh_bytes + CAP_STEPS * action.nbytes + PICKLE_SLACK_BYTES
    for _ in range(CAP_STEPS):
        env.step(action)
    assert _pickled_bytes(env) <= bound
    kept_bytes = env.unwrapped._history.nbytes
    assert kept_bytes <= CAP_STEPS * action.nbytes

    for _ in range(9 * CAP_STEPS):  # ten times the steps
        env.step(action)
    assert env.unwrapped._history.nbytes == kept_bytes
    for copier in (pickle.dumps, copy.deepcopy):
        with pytest.raises(pickle.PicklingError, match="copy_history_max_steps=40") as info:
            copier(env)
        assert type(info.value).__name__ == "EpisodeTooLongToCopyError"
        assert f"at step {10 * CAP_STEPS}" in str(info.value)
        assert "reset()" in str(info.value)

    # A reset starts a new history: the env copies again, and the copy steps on alike.
    env.reset(seed=1)
    env.step(action)
    twin = pickle.loads(pickle.dumps(env))
    try:
        assert twin.unwrapped.copy_history_max_steps == CAP_STEPS
        assert data_equivalence(twin.step(action), env.step(action))
    finally:
        twin.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_a_copy_at_the_limit_steps_on_like_the_original(make_env, env_id):
    env = make_env(env_id, obs_mode="measurements")
    env.unwrapped.copy_history_max_steps = 5
    env.reset(seed=3)
    rng = np.random.default_rng(0)
    space = env.action_space
    actions = [(rng.uniform(space.low, space.high) * 0.3).astype(space.dtype) for _ in range(8)]
    for a in actions[:5]:
        env.step(a)
    twin = copy.deepcopy(env)
    try:
        for a in actions[5:]:
            assert data_equivalence(twin.step(a), env.step(a))
    finally:
        twin.close()


@pytest.mark.parametrize("bad", [-1, 2.5, True, "10", None])
def test_a_bad_copy_history_max_steps_is_refused_at_reset(make_env, bad):
    env = make_env("observer_gym/BallTable-v0", obs_mode="state")
    env.unwrapped.copy_history_max_steps = bad
    with pytest.raises(ValueError, match=r"copy_history_max_steps must be an int >= 0"):
        env.reset(seed=0)


def test_a_limit_of_zero_steps_copies_only_at_the_reset(make_env):
    env = make_env("observer_gym/TargetFollower-v0", obs_mode="state")
    env.unwrapped.copy_history_max_steps = 0
    env.reset(seed=0)
    copy.deepcopy(env).close()
    env.step(_zero_action(env))
    with pytest.raises(pickle.PicklingError, match="at step 1"):
        copy.deepcopy(env)
