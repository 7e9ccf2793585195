"""PointMass-v0's controller: PD on position and velocity."""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from observer_gym.controllers.base import StateFeedbackController
from observer_gym.controllers.registry import ControllerDesign
from observer_gym.envs.config import real_number


class PointMassPlant(NamedTuple):
    obs_dim: int
    max_accel_mps2: float

    @classmethod
    def from_env(cls, env: Any) -> PointMassPlant:
        base = env.unwrapped
        return cls(base.state_space.shape[0], float(base.config.max_accel_mps2))


class PDController(StateFeedbackController):
    """a = clip(-kp x - kd v): critically damped at kp = 4, kd = 4 (1/s^2, 1/s)."""

    name = "pd"

    def __init__(self, plant: PointMassPlant, kp: float = 4.0, kd: float = 4.0) -> None:
        bound = np.full(2, plant.max_accel_mps2)
        super().__init__(plant.obs_dim, -bound, bound)
        self.kp = real_number("kp", kp, 0.0, 1e3)
        self.kd = real_number("kd", kd, 0.0, 1e3)

    def act(self, obs: np.ndarray, episode_start: np.ndarray) -> np.ndarray:
        action = -self.kp * obs[:, 0:2] - self.kd * obs[:, 2:4]
        return np.clip(action, self.action_low, self.action_high)


CONTROLLERS = {"pd": ControllerDesign(PDController, PointMassPlant.from_env, "PD on the state")}
