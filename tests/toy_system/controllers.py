"""PointMass-v0's controllers: a PD on position and velocity, and the package's generic
LQR designed from :class:`PointMassPlant` (a ``LinearPlant``, controllers/plant.py)."""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from observer_gym.controllers.base import StateFeedbackController
from observer_gym.controllers.lqr import LQRController
from observer_gym.controllers.registry import ControllerDesign
from observer_gym.envs.config import real_number


class PointMassPlant(NamedTuple):
    """One env step of the point mass, x = (x, y, vx, vy), u = (ax, ay)."""

    dt_s: float
    obs_dim: int
    max_accel_mps2: float

    @classmethod
    def from_env(cls, env: Any) -> PointMassPlant:
        base = env.unwrapped
        return cls(base.dt_s, base.state_space.shape[0], float(base.config.max_accel_mps2))

    @property
    def state_slice(self) -> slice:
        return slice(0, 4)

    @property
    def action_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        bound = np.full(2, self.max_accel_mps2)
        return -bound, bound

    def matrices(self) -> tuple[np.ndarray, np.ndarray]:
        # p' = p + v dt + a dt^2 / 2, v' = v + a dt (the exact double integrator)
        dt = self.dt_s
        A = np.eye(4)
        A[0, 2] = A[1, 3] = dt
        B = np.vstack([0.5 * dt * dt * np.eye(2), dt * np.eye(2)])
        return A, B

    def weights(self) -> tuple[np.ndarray, np.ndarray]:
        # Bryson's rule: 1 cm, 5 cm/s, the whole acceleration range
        return np.diag([1e4, 1e4, 400.0, 400.0]), np.eye(2) / self.max_accel_mps2**2


class PDController(StateFeedbackController):
    """a = clip(-kp x - kd v): critically damped at kp = 4, kd = 4 (1/s^2, 1/s)."""

    name = "pd"

    def __init__(self, plant: PointMassPlant, kp: float = 4.0, kd: float = 4.0) -> None:
        low, high = plant.action_bounds
        super().__init__(plant.obs_dim, low, high)
        self.kp = real_number("kp", kp, 0.0, 1e3)
        self.kd = real_number("kd", kd, 0.0, 1e3)

    def act(self, obs: np.ndarray, episode_start: np.ndarray) -> np.ndarray:
        action = -self.kp * obs[:, 0:2] - self.kd * obs[:, 2:4]
        return np.clip(action, self.action_low, self.action_high)


CONTROLLERS = {
    "pd": ControllerDesign(PDController, PointMassPlant.from_env, "PD on the state"),
    "lqr": ControllerDesign(LQRController, PointMassPlant.from_env, "the generic LQR"),
}
