"""The observer reads the action the env applied (``info["applied_action"]``), so a wrapper
that rescales actions between it and the env cannot make it believe another command."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium.wrappers import RescaleAction

from observer_gym.envs.ball_table import StateIndex
from observer_gym.estimation import VisionObserver


def test_an_observer_over_rescale_action_estimates_the_applied_tilt():
    env = gym.make("observer_gym/BallTable-v0", obs_mode="measurements")
    one = np.ones(2, np.float32)
    observed = VisionObserver(RescaleAction(env, -one, one))
    try:
        observed.reset(seed=0, options={"ball_pos_table_m": (0, 0), "ball_vel_table_mps": (0, 0)})
        errors = []
        for _ in range(20):
            # 0.5 in [-1, 1] is 0.05 rad of the env's +-0.1 rad.
            estimate, *_, info = observed.step(np.array([0.5, 0.5], np.float32))
            np.testing.assert_allclose(info["applied_action"], [0.05, 0.05], atol=1e-7)
            tilt = slice(StateIndex.TILT_X, StateIndex.TILT_Y + 1)
            errors.append(np.max(np.abs(estimate[tilt] - info["state"][tilt])))
        # The commanded tilt is followed within ~0.1 s; the estimate follows the truth.
        assert np.median(errors) < 0.005, errors
    finally:
        observed.close()
