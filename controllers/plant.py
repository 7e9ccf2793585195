"""What a controller designs from: the env's nominal model, its step and its action bounds."""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from observer_gym.envs.ball_catcher import STATE_DIM as CATCHER_STATE_DIM
from observer_gym.envs.ball_catcher import BallCatcherEnv
from observer_gym.envs.ball_catcher import geometry as catcher_geometry
from observer_gym.envs.ball_table import STATE_DIM, BallTableEnv
from observer_gym.estimation.ball_table_model import BallTableControlModel
from observer_gym.estimation.models import BallisticModel

__all__ = ["BallCatcherPlant", "BallTablePlant", "unwrapped_env"]


def unwrapped_env(env: gym.Env, env_class: type, env_id: str, needed_by: str) -> gym.Env:
    """The base env under ``env``'s wrappers; ValueError unless it is an ``env_class``."""
    base = env.unwrapped
    if not isinstance(base, env_class):
        raise ValueError(f"{needed_by} needs a {env_id} env, got {type(base).__name__}")
    return base


@dataclass(frozen=True)
class BallTablePlant:
    """BallTable-v0 as the controllers see it: the 6-state model of
    estimation/ball_table_model.py discretised at the env's step, with the bound on the
    commanded tilt. Observations have the env's 8-entry state layout; the model's state is
    their first six entries."""

    model: BallTableControlModel
    dt_s: float
    max_tilt_rad: float
    obs_dim: int = STATE_DIM

    @classmethod
    def from_env(cls, env: gym.Env) -> BallTablePlant:
        cfg = unwrapped_env(env, BallTableEnv, "BallTable-v0", "the BallTable controllers").config
        return cls(BallTableControlModel.from_config(cfg), cfg.dt_s, cfg.max_tilt_rad)

    def matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """(Phi, Gamma) of one env step, exact zero-order hold."""
        Phi, Gamma, _ = self.model.matrices(self.dt_s)
        return np.array(Phi), np.array(Gamma)

    @property
    def action_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        bound = np.full(2, self.max_tilt_rad)
        return -bound, bound


@dataclass(frozen=True)
class BallCatcherPlant:
    """BallCatcher-v0 as the intercept controller sees it: the control period, the robot
    profile's limits, the box's workspace and home, and gravity. Observations have the
    env's 12-entry state layout (ball position and velocity, box position and velocity)."""

    dt_s: float
    max_speed_mps: float
    max_accel_mps2: float
    workspace_low_world: np.ndarray
    workspace_high_world: np.ndarray
    home_world: np.ndarray
    gravity_mps2: float
    obs_dim: int = CATCHER_STATE_DIM

    @classmethod
    def from_env(cls, env: gym.Env) -> BallCatcherPlant:
        base = unwrapped_env(env, BallCatcherEnv, "BallCatcher-v0", "the intercept controller")
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
