"""The "doing nothing" baseline of the benchmark's floor: a controller that always
applies the zero action (BallTable: a level table; BallCatcher: the box stands still;
TargetFollower: the robot and its camera stand still).

Entered by import path, ``observer_gym.train.experiments.benchmark.idle:make_idle``, as
any outside controller is (docs/your_method.md).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np


class Idle:
    """Always the zero action of the env's action space."""

    name = "idle"

    def __init__(self, env: gym.Env) -> None:
        space = env.action_space
        if not isinstance(space, gym.spaces.Box):
            raise ValueError(f"the idle controller needs a Box action space, got {space}")
        if not (np.all(space.low <= 0.0) and np.all(space.high >= 0.0)):
            raise ValueError(f"the zero action is outside the action space {space}")
        self._zero = np.zeros(space.shape, dtype=space.dtype)

    def reset(self) -> None:
        """Nothing to reset."""

    def predict(
        self, obs: Any, state: Any = None, episode_start: Any = None, deterministic: bool = True
    ) -> tuple[np.ndarray, None]:
        """The zero action, whatever the observation."""
        return self._zero.copy(), None


def make_idle(env: gym.Env) -> Idle:
    """The idle controller for ``env`` (the outside controller factory's signature)."""
    return Idle(env)
