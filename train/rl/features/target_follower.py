"""TargetFollower-v0's observation features for agents.

``tracking``: what the reward and the VTC depend on, computed from the state or the
observer's estimate, in the reward's own units, without the robot's pose on the floor.
The 15 state entries include the robot's position and heading (x, y, yaw), which drift
without bound over an episode and tell nothing about the image the reward scores; the
VTC (controllers/target_follower/vtc.py) does not read them either. The 12 entries:

- the image errors the reward scores, each over its scale there:
  x_i / (W / 2), y_i / (H / 2), (d_x - d*) / d*, clipped to +-ERROR_LIMIT;
- their target-induced rates over the same scales (1/s), clipped to +-RATE_LIMIT_PER_S;
- the camera's tilt (rad) and the velocity applied over the last step (v, omega,
  omega_t), as in the state;
- ``tracking_valid`` and ``target_visible``.
"""

from __future__ import annotations

from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from observer_gym.envs.target_follower import StateIndex
from observer_gym.envs.target_follower.layout import APPLIED, IMAGE, IMAGE_RATE, STATE_DIM

# An error beyond the scale is off the image (the reward's term saturates at 1 there); a
# few scales keep the direction back without the unbounded values of a lost target.
ERROR_LIMIT = 3.0
RATE_LIMIT_PER_S = 30.0
FEATURE_NAMES = (
    "x_i_error",
    "y_i_error",
    "d_x_error",
    "x_i_error_rate_per_s",
    "y_i_error_rate_per_s",
    "d_x_error_rate_per_s",
    "tilt_rad",
    "applied_speed_mps",
    "applied_yaw_rate_radps",
    "applied_tilt_rate_radps",
    "tracking_valid",
    "target_visible",
)


class TrackingFeatures(gym.Wrapper):
    """Replaces the 15 state entries by the 12 of :data:`FEATURE_NAMES` (module
    docstring); the scales W, H (px) and d* (px) are the env's ``image_width_px``,
    ``image_height_px`` and ``desired_width_px``."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        space = env.observation_space
        if not (isinstance(space, spaces.Box) and space.shape == (STATE_DIM,)):
            raise ValueError(
                f"features 'tracking' need the state's layout ({STATE_DIM} entries: obs "
                f"state or estimate), got the observation space {space}"
            )
        config = env.unwrapped.config  # type: ignore[attr-defined]
        # the reward's scales: 1 - mean_j min(|e_j| / s_j, 1), s = (W/2, H/2, d*)
        self.scale_px = np.array(
            [config.image_width_px / 2.0, config.image_height_px / 2.0, config.desired_width_px]
        )
        self.desired_width_px = float(config.desired_width_px)
        rest_high = np.concatenate([[space.high[StateIndex.TILT]], space.high[APPLIED], [1.0, 1.0]])
        rest_low = np.concatenate([[space.low[StateIndex.TILT]], space.low[APPLIED], [0.0, 0.0]])
        high = np.concatenate([np.full(3, ERROR_LIMIT), np.full(3, RATE_LIMIT_PER_S), rest_high])
        low = np.concatenate([-np.full(3, ERROR_LIMIT), -np.full(3, RATE_LIMIT_PER_S), rest_low])
        self.observation_space = spaces.Box(
            low.astype(np.float32), high.astype(np.float32), dtype=np.float32
        )

    def features(self, observation: np.ndarray) -> np.ndarray:
        """The 12 entries for one state-layout observation."""
        state = np.asarray(observation, dtype=float)
        image_px = state[IMAGE] - np.array([0.0, 0.0, self.desired_width_px])
        error = np.clip(image_px / self.scale_px, -ERROR_LIMIT, ERROR_LIMIT)
        rate = np.clip(state[IMAGE_RATE] / self.scale_px, -RATE_LIMIT_PER_S, RATE_LIMIT_PER_S)
        rest = np.concatenate(
            [
                [state[StateIndex.TILT]],
                state[APPLIED],
                state[[StateIndex.TRACKING_VALID, StateIndex.TARGET_VISIBLE]],
            ]
        )
        return np.concatenate([error, rate, rest]).astype(np.float32)

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict[str, Any]]:
        observation, info = self.env.reset(**kwargs)
        return self.features(observation), info

    def step(self, action: Any) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict[str, Any]]:
        observation, reward, terminated, truncated, info = self.env.step(action)
        return self.features(observation), reward, terminated, truncated, info
