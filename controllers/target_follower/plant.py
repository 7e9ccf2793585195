"""The design input of the TargetFollower controllers, read from the env."""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from observer_gym.controllers.base import unwrapped_env
from observer_gym.envs.target_follower import TargetFollowerEnv
from observer_gym.estimation.target_follower.models import TargetFollowerCameraParams

__all__ = ["TargetFollowerPlant"]


@dataclass(frozen=True)
class TargetFollowerPlant:
    """What a TargetFollower controller is designed from: the nominal camera parameters
    of B_i, the set point X_i* = (0, 0, d*), the sample time and the action bounds."""

    camera: TargetFollowerCameraParams
    desired_px: tuple[float, float, float]
    dt_s: float
    action_low: np.ndarray
    action_high: np.ndarray
    obs_dim: int

    @classmethod
    def from_env(cls, env: gym.Env) -> TargetFollowerPlant:
        """From a TargetFollower env (any wrapper around it); ValueError for another env."""
        base = unwrapped_env(env, TargetFollowerEnv, "TargetFollower-v0", "TargetFollowerPlant")
        calibration = base.calibration
        return cls(
            camera=TargetFollowerCameraParams.from_calibration(calibration),
            desired_px=(0.0, 0.0, float(base.config.desired_width_px)),
            dt_s=float(calibration["dt_s"]),
            action_low=np.asarray(base.action_space.low, dtype=float),
            action_high=np.asarray(base.action_space.high, dtype=float),
            obs_dim=int(base.state_space.shape[0]),
        )
