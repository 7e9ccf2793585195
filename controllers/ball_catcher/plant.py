"""What the intercept controller designs from: the control period, the robot's limits, the
box's workspace and home, and gravity."""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from observer_gym.controllers.base import unwrapped_env
from observer_gym.envs.ball_catcher import STATE_DIM, BallCatcherEnv
from observer_gym.envs.ball_catcher import geometry as catcher_geometry
from observer_gym.estimation.ball_catcher.models import BallisticModel

__all__ = ["BallCatcherPlant"]


@dataclass(frozen=True)
class BallCatcherPlant:
    """BallCatcher-v1 as the intercept controller sees it: the control period, the robot
    profile's limits, the box's workspace and home, and gravity. Observations have the
    env's 12-entry state layout (ball position and velocity, box position and velocity)."""

    dt_s: float
    max_speed_mps: float
    max_accel_mps2: float
    workspace_low_world: np.ndarray
    workspace_high_world: np.ndarray
    home_world: np.ndarray
    gravity_mps2: float
    obs_dim: int = STATE_DIM

    @classmethod
    def from_env(cls, env: gym.Env) -> BallCatcherPlant:
        base = unwrapped_env(env, BallCatcherEnv, "BallCatcher-v1", "the intercept controller")
        cfg = base.config
        return cls(
            cfg.control_dt_s,
            cfg.profile.max_speed_mps,
            cfg.profile.max_accel_mps2,
            catcher_geometry.WORKSPACE_LOW_WORLD.copy(),
            catcher_geometry.WORKSPACE_HIGH_WORLD.copy(),
            catcher_geometry.HOLE_HOME_WORLD.copy(),
            BallisticModel().gravity_mps2,
        )

    @property
    def action_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        bound = np.full(3, self.max_speed_mps)
        return -bound, bound
