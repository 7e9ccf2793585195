"""What the BallTable controllers design from: the nominal model, the step, the bounds."""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from observer_gym.controllers.base import unwrapped_env
from observer_gym.envs.ball_table import STATE_DIM, BallTableEnv
from observer_gym.estimation.ball_table.control_model import BallTableControlModel

__all__ = ["BallTablePlant", "check_plant"]


@dataclass(frozen=True)
class BallTablePlant:
    """BallTable-v0 as the controllers see it: the 6-state model of
    estimation/ball_table/control_model.py discretised at the env's step, with the bound on the
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


def check_plant(owner: str, plant: object) -> None:
    """ValueError unless ``plant`` is a :class:`BallTablePlant` (make one with
    ``BallTablePlant.from_env(env)``, or use ``make_controller``)."""
    if not isinstance(plant, BallTablePlant):
        raise ValueError(
            f"{owner}: plant must be a BallTablePlant (BallTablePlant.from_env(env)), got "
            f"{type(plant).__name__}"
        )
