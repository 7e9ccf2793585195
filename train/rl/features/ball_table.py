"""BallTable-v0's observation features for agents.

``belief``: the observer's belief, mean and uncertainty: the 8 state entries (the
estimate, or the true state) followed by the standard deviation of each, the square root
of the diagonal of the observer's ``info["estimate"]`` covariance (0 without an estimate:
the true state is certain), clipped to :data:`STD_LIMIT` of the entry's bound. An agent
reads what the observer believes and how sure it is, as a controller of the estimate
cannot.
"""

from __future__ import annotations

from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from observer_gym.envs.ball_table.layout import STATE_DIM

# a standard deviation beyond this fraction of the entry's range carries no more information
STD_LIMIT = 1.0


class BeliefFeatures(gym.Wrapper):
    """The 8 state entries and their 8 standard deviations (module docstring)."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        space = env.observation_space
        if not (isinstance(space, spaces.Box) and space.shape == (STATE_DIM,)):
            raise ValueError(
                f"features 'belief' need the state's layout ({STATE_DIM} entries: obs state "
                f"or estimate), got the observation space {space}"
            )
        self.std_high = (STD_LIMIT * np.asarray(space.high, dtype=np.float64)).astype(np.float32)
        self.observation_space = spaces.Box(
            np.concatenate([space.low, np.zeros(STATE_DIM, np.float32)]),
            np.concatenate([space.high, self.std_high]),
            dtype=np.float32,
        )

    def features(self, observation: np.ndarray, info: dict[str, Any]) -> np.ndarray:
        """The 16 entries for one observation and its step's ``info``."""
        std = np.zeros(STATE_DIM)
        estimate = info.get("estimate")
        if estimate is not None:
            std = np.sqrt(np.maximum(np.diag(np.asarray(estimate["covariance"])), 0.0))
        std = np.minimum(std, self.std_high)
        return np.concatenate([np.asarray(observation, np.float32), std]).astype(np.float32)

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict[str, Any]]:
        observation, info = self.env.reset(**kwargs)
        return self.features(observation, info), info

    def step(self, action: Any) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict[str, Any]]:
        observation, reward, terminated, truncated, info = self.env.step(action)
        return self.features(observation, info), reward, terminated, truncated, info
