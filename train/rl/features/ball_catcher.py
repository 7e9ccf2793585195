"""BallCatcher-v1's observation features for agents.

``crossing``: what intercepting the ball depends on, computed from the state or the
observer's estimate: where the ball, flying on without drag, will cross the box's front
plane relative to the hole, how soon, how uncertain that point is, and the box's own
motion. The intercept planner computes the same point and uncertainty
(``controllers/ball_catcher/intercept.py``). PPO on the 12 state entries of the estimate
did not learn to catch within 150,000 steps; on these features it does
(docs/results/ball_catcher.md, "What made it learnable").
"""

from __future__ import annotations

from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from observer_gym.controllers.ball_catcher.intercept import crossing_and_jacobian
from observer_gym.envs.ball_catcher import geometry as geo
from observer_gym.envs.ball_catcher.layout import BALL, BOX_POS, BOX_VEL, STATE_DIM
from observer_gym.envs.sim import GRAVITY_MPS2

# Bounds of the entries: a predicted miss or uncertainty beyond the workspace's reach
# carries no more information, and an early estimate can be metres off.
MISS_LIMIT_M = 0.5
TIME_LIMIT_S = 1.0
FEATURE_NAMES = (
    "miss_y_m",
    "miss_z_m",
    "time_to_plane_s",
    "approaching",
    "miss_std_m",
    "box_dx_m",
    "box_dy_m",
    "box_dz_m",
    "box_vx_mps",
    "box_vy_mps",
    "box_vz_mps",
)


class CrossingFeatures(gym.Wrapper):
    """Replaces the 12 state entries by the 11 of :data:`FEATURE_NAMES`.

    With the ball's position p and velocity v and the hole's position b (all from the
    observation), the ball reaches the plane x = b_x after t = (b_x - p_x) / v_x and
    crosses it at c = p + v t - (0, 0, g t^2 / 2):

    - miss_y_m, miss_z_m: c_y - b_y, c_z - b_z, clipped to +-MISS_LIMIT_M;
    - time_to_plane_s: t, clipped to [0, TIME_LIMIT_S];
    - approaching: 1 (0 when the ball does not approach the plane: then the first five
      entries are 0);
    - miss_std_m: the larger standard deviation of (c_y, c_z) to first order,
      sqrt(max eig(J P J^T)) with J = d(c_y, c_z)/d(p, v) and P the ball's covariance
      from the observer's ``info["estimate"]`` (0 without an estimate: the true state),
      clipped to MISS_LIMIT_M;
    - box_d*_m: the hole's position minus its home; box_v*_mps: its velocity.
    """

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        space = env.observation_space
        if not (isinstance(space, spaces.Box) and space.shape == (STATE_DIM,)):
            raise ValueError(
                f"features 'crossing' need the state's layout ({STATE_DIM} entries: obs state "
                f"or estimate), got the observation space {space}"
            )
        box_pos = space.high[BOX_POS]
        box_vel = space.high[BOX_VEL]
        high = np.concatenate(
            [[MISS_LIMIT_M, MISS_LIMIT_M, TIME_LIMIT_S, 1.0, MISS_LIMIT_M], box_pos, box_vel]
        ).astype(np.float32)
        low = np.concatenate([[-MISS_LIMIT_M, -MISS_LIMIT_M, 0.0, 0.0, 0.0], -box_pos, -box_vel])
        self.observation_space = spaces.Box(low.astype(np.float32), high, dtype=np.float32)

    def features(self, observation: np.ndarray, info: dict[str, Any]) -> np.ndarray:
        """The 11 entries for one observation and its step's ``info``."""
        state = np.asarray(observation, dtype=float)
        box = state[BOX_POS]
        crossing = crossing_and_jacobian(state[BALL], box[0], GRAVITY_MPS2)
        extra = np.zeros(5)
        if crossing is not None:
            t_s, point, J = crossing
            std_m = 0.0
            estimate = info.get("estimate")
            if estimate is not None:
                P = np.asarray(estimate["covariance"])[BALL, BALL]
                std_m = float(np.sqrt(max(np.linalg.eigvalsh(J @ P @ J.T)[-1], 0.0)))
            miss = np.clip(point[1:] - box[1:], -MISS_LIMIT_M, MISS_LIMIT_M)
            extra = np.array(
                [miss[0], miss[1], min(t_s, TIME_LIMIT_S), 1.0, min(std_m, MISS_LIMIT_M)]
            )
        box_offset = box - geo.HOLE_HOME_WORLD
        return np.concatenate([extra, box_offset, state[BOX_VEL]]).astype(np.float32)

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict[str, Any]]:
        observation, info = self.env.reset(**kwargs)
        return self.features(observation, info), info

    def step(self, action: Any) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict[str, Any]]:
        observation, reward, terminated, truncated, info = self.env.step(action)
        return self.features(observation, info), reward, terminated, truncated, info
