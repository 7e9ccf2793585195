"""The env runs in spawned worker processes (SB3's SubprocVecEnv and Gymnasium's
AsyncVectorEnv): it pickles, registers itself on import, and steps the same as in-process."""

from __future__ import annotations

import functools

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AsyncVectorEnv
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import SubprocVecEnv

import observer_gym.envs  # noqa: F401  (registers the envs in this process)

# "module:id": gym.make imports the module first, so a spawned worker registers the env.
SPAWN_ENV_ID = "observer_gym.envs:observer_gym/BallTable-v0"
N_WORKERS = 2
N_STEPS = 20
SEED = 123


def _in_process_trajectory(seed: int, n_steps: int) -> list[np.ndarray]:
    """What make_vec_env's worker does: gym.make with render_mode="rgb_array" (its default
    for string ids), then a first reset with seed + rank (VecEnv.seed), then the steps."""
    env = gym.make(SPAWN_ENV_ID, render_mode="rgb_array", obs_mode="state")
    try:
        obs, _ = env.reset(seed=seed)
        trajectory = [obs]
        for _ in range(n_steps):
            obs, *_ = env.step(np.zeros(2, dtype=np.float32))
            trajectory.append(obs)
        return trajectory
    finally:
        env.close()


# spawned SB3 workers (5 s idle): slow; the AsyncVectorEnv spawn test stays in the default run
@pytest.mark.slow
def test_sb3_subproc_vec_env_with_spawn_matches_in_process_env():
    vec_env = make_vec_env(
        SPAWN_ENV_ID,
        n_envs=N_WORKERS,
        seed=SEED,
        vec_env_cls=SubprocVecEnv,
        vec_env_kwargs={"start_method": "spawn"},
        env_kwargs={"obs_mode": "state"},
    )
    try:
        obs = vec_env.reset()
        trajectory = [obs]
        actions = np.zeros((N_WORKERS, 2), dtype=np.float32)
        for _ in range(N_STEPS):
            obs, _, dones, _ = vec_env.step(actions)
            assert not dones.any(), "an episode ended; the comparison below assumes none does"
            trajectory.append(obs)
    finally:
        vec_env.close()

    for obs in trajectory:
        assert obs.shape == (N_WORKERS, 8)
        assert np.all(np.isfinite(obs))
    assert not np.array_equal(trajectory[0][0], trajectory[0][1]), (
        "workers seeded with different seeds started from the same state"
    )
    for rank in range(N_WORKERS):
        expected = _in_process_trajectory(SEED + rank, N_STEPS)
        got = [obs[rank] for obs in trajectory]
        np.testing.assert_array_equal(np.stack(got), np.stack(expected), err_msg=f"rank {rank}")


def test_gymnasium_async_vector_env_with_spawn_in_measurements_mode():
    make = functools.partial(gym.make, SPAWN_ENV_ID, obs_mode="measurements")
    vec_env = AsyncVectorEnv([make] * N_WORKERS, context="spawn")
    try:
        obs, _ = vec_env.reset(seed=SEED)
        actions = np.zeros((N_WORKERS, 2), dtype=np.float32)
        for _ in range(5):
            obs, _, terminated, truncated, _ = vec_env.step(actions)
            assert not terminated.any() and not truncated.any()
    finally:
        vec_env.close()

    assert set(obs) == {"table_corners_px", "ball_px", "detected"}
    assert obs["table_corners_px"].shape == (N_WORKERS, 8)
    assert obs["ball_px"].shape == (N_WORKERS, 3)
    assert obs["detected"].shape == (N_WORKERS, 2)
    assert np.all(np.isfinite(obs["table_corners_px"]))
    assert np.all(np.isfinite(obs["ball_px"]))
    # A perfect detector, no occluder, ball resting near the centre: both are seen.
    assert np.all(obs["detected"] == 1)
