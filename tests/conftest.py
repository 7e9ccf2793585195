"""Shared fixtures: every env a test makes is closed, whatever the test's outcome.

The toy fourth system of tests/toy_system is registered here, before collection, so the
env suite (tests/envs/test_envs.py, test_copies.py) runs on it beside the package's.
"""

from __future__ import annotations

import gymnasium as gym
import pytest
import toy_system

import observer_gym.envs

toy_system.register()
ENV_IDS = observer_gym.envs.ENV_IDS
# every registered system's env: the package's and the toy
SUITE_IDS = tuple(system.env_id for system in observer_gym.envs.SYSTEMS)
OBS_MODES = ("rgb", "state", "measurements")


@pytest.fixture
def make_env():
    """``make_env(env_id, **kwargs)`` -> a gym.make'd env, closed at teardown."""
    made = []

    def factory(env_id: str = "observer_gym/BallTable-v0", **kwargs):
        env = gym.make(env_id, **kwargs)
        made.append(env)
        return env

    yield factory
    for env in made:
        env.close()


TINY_RUN_STEPS = 64  # env steps per checkpoint of the tiny run: one rollout of one env


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory):
    """A finished 128-step PPO run on BallTable's state (checkpoints at 64 and 128 steps,
    one evaluation), built once per test process for the tests that need a training run's
    folder: copy it before changing anything in it."""
    from observer_gym.train.rl.training import train_agent  # deferred: imports PyTorch

    out_dir = tmp_path_factory.mktemp("tiny_run") / "run"
    steps = TINY_RUN_STEPS
    state = train_agent(
        "BallTable-v0", "ppo", "state", out_dir, timesteps=2 * steps, n_envs=1, vec_env="dummy",
        hyperparams={"n_steps": steps, "batch_size": steps, "checkpoint_freq": steps,
                     "eval_freq": 10_000, "eval_episodes": 1},
        progress=False,
    )  # fmt: skip
    assert state["status"] == "finished"
    return out_dir
