"""What the BallTable controllers design from: the nominal model, the step, the bounds.

:class:`BallTablePlant` is the generic designs' plant (controllers/plant.py): a
``LinearPlant`` for the LQR, a ``ConstrainedPlant`` for the MPC, an ``AxesPlant`` for the
PID.
"""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from observer_gym.controllers.ball_table.weights import ball_table_weights
from observer_gym.controllers.base import unwrapped_env
from observer_gym.controllers.plant import DoubleIntegratorAxes, StageBound
from observer_gym.envs.ball_table import STATE_DIM, BallTableEnv
from observer_gym.envs.ball_table.geometry import BALL_TRAVEL_M
from observer_gym.estimation.ball_table.control_model import BallTableControlModel

__all__ = ["DEFAULT_TILT_RATE_LIMIT_RADPS", "BallTablePlant", "check_ball_table_plant"]

DEFAULT_TILT_RATE_LIMIT_RADPS = 1.5  # the MPC's default bound on the table's tilt rate

_BALL = slice(0, 2)  # p in the model's state (p, v, theta)
_VELOCITY = slice(2, 4)  # v
_TILT = slice(4, 6)  # theta


@dataclass(frozen=True)
class BallTablePlant:
    """BallTable-v0 as the controllers see it: the 6-state model of
    estimation/ball_table/control_model.py discretised at the env's step, with the bound on the
    commanded tilt. Observations have the env's 8-entry state layout; the model's state is
    their first six entries (``state_slice``), the model's input the env's action."""

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
    def state_slice(self) -> slice:
        """The model's state (p, v, theta) in the observation: its first six entries."""
        return slice(0, self.model.n)

    @property
    def action_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        bound = np.full(2, self.max_tilt_rad)
        return -bound, bound

    def weights(self) -> tuple[np.ndarray, np.ndarray]:
        """The default (Q, R): :func:`ball_table_weights` (Bryson's rule)."""
        return ball_table_weights()

    def constraints(
        self,
        tilt_limit_rad: float | None = None,
        tilt_rate_limit_radps: float = DEFAULT_TILT_RATE_LIMIT_RADPS,
        ball_limit_m: float = BALL_TRAVEL_M,
    ) -> tuple[StageBound, ...]:
        """The MPC's bounds, in this order (tau the arm's tilt lag):

            |u_k| <= tilt_limit                           (commanded tilt)
            |theta_k| <= tilt_limit,             k = 1..N (table tilt)
            |u_k - theta_k| <= tau * rate_limit, k < N    (tilt rate (u - theta) / tau)
            |p_k| <= ball_limit,                 k = 1..N (ball on the table)

        ``tilt_limit_rad`` defaults to (and is capped at) the env's bound; ``ball_limit_m``
        to L/2 - r, the ball touching a border. Not checked here: ``BallTableMPC`` checks
        its options (each > 0), every MPC its bounds (finite, >= 0)."""
        n, m = self.model.n, self.model.m
        tilt_limit = self.max_tilt_rad if tilt_limit_rad is None else tilt_limit_rad
        tilt_limit = min(tilt_limit, self.max_tilt_rad)
        none_of_x, none_of_u, every_u = np.zeros((m, n)), np.zeros((m, m)), np.eye(m)
        tilt_of_x = np.zeros((m, n))
        tilt_of_x[:, _TILT] = np.eye(m)
        ball_of_x = np.zeros((2, n))
        ball_of_x[:, _BALL] = np.eye(2)
        return (
            StageBound("commanded tilt", none_of_x, every_u, np.full(m, tilt_limit)),
            StageBound("table tilt", tilt_of_x, none_of_u, np.full(m, tilt_limit), True),
            # (u - theta) / tau <= rate  <=>  |u - theta| <= tau rate
            StageBound(
                "tilt rate",
                -tilt_of_x,
                every_u,
                np.full(m, self.model.tau_s * tilt_rate_limit_radps),
            ),
            StageBound(
                "ball on the table", ball_of_x, np.zeros((2, m)), np.full(2, ball_limit_m), True
            ),
        )

    def axes(self) -> DoubleIntegratorAxes:
        """The ball's two axes for the PID: p = obs[0:2], v = obs[2:4], v' = G theta with
        G = (5/7) g [[0, 1], [-1, 0]] (:func:`tilt_to_acceleration`)."""
        return DoubleIntegratorAxes(_BALL, _VELOCITY, self.model.G)


def check_ball_table_plant(owner: str, plant: object) -> None:
    """ValueError unless ``plant`` is a :class:`BallTablePlant` (make one with
    ``BallTablePlant.from_env(env)``, or use ``make_controller``)."""
    if not isinstance(plant, BallTablePlant):
        raise ValueError(
            f"{owner}: plant must be a BallTablePlant (BallTablePlant.from_env(env)), got "
            f"{type(plant).__name__}"
        )
