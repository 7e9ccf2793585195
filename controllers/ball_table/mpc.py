"""BallTable's MPC: the generic MPC (controllers/mpc.py) with the table's bounds as options.

The bounds are :meth:`BallTablePlant.constraints`: the commanded tilt, the table's tilt,
the tilt rate (u - theta) / tau and the ball on the table.
"""

from __future__ import annotations

from observer_gym.controllers.ball_table.plant import (
    DEFAULT_TILT_RATE_LIMIT_RADPS,
    BallTablePlant,
    check_ball_table_plant,
)
from observer_gym.controllers.base import check_number
from observer_gym.controllers.mpc import MPCController
from observer_gym.envs.ball_table.geometry import BALL_TRAVEL_M

__all__ = ["BallTableMPC"]


class BallTableMPC(MPCController):
    """:class:`MPCController` on a :class:`BallTablePlant` with its bounds given by name.

    Arguments: ``plant``; ``horizon``, ``Q``, ``R``, ``constrained``, ``osqp_settings`` as
    for :class:`MPCController`; ``tilt_limit_rad`` (default the env's bound, capped at
    it), ``tilt_rate_limit_radps`` (default 1.5), ``ball_limit_m`` (default L/2 - r, the
    ball touching a border). Numbers may be Python's or NumPy's; a bad option raises
    ``ValueError`` naming it and what it allows.
    Attributes: those of :class:`MPCController`, and the three limits as used.
    """

    def __init__(
        self,
        plant: BallTablePlant,
        horizon: int = 20,
        Q=None,
        R=None,
        constrained: bool = True,
        tilt_limit_rad: float | None = None,
        tilt_rate_limit_radps: float = DEFAULT_TILT_RATE_LIMIT_RADPS,
        ball_limit_m: float = BALL_TRAVEL_M,
        osqp_settings: dict | None = None,
    ) -> None:
        check_ball_table_plant("BallTableMPC", plant)
        owner = "BallTableMPC"
        tilt_limit = check_number(
            owner, "tilt_limit_rad", tilt_limit_rad, low=0.0, low_inclusive=False, allow_none=True
        )
        tilt_limit = plant.max_tilt_rad if tilt_limit is None else tilt_limit
        tilt_rate_limit_radps = check_number(
            owner, "tilt_rate_limit_radps", tilt_rate_limit_radps, low=0.0, low_inclusive=False
        )
        ball_limit_m = check_number(
            owner, "ball_limit_m", ball_limit_m, low=0.0, low_inclusive=False
        )
        self.tilt_limit_rad = min(tilt_limit, plant.max_tilt_rad)
        self.tilt_rate_limit_radps = tilt_rate_limit_radps
        self.ball_limit_m = ball_limit_m
        bounds = plant.constraints(self.tilt_limit_rad, tilt_rate_limit_radps, ball_limit_m)
        super().__init__(plant, horizon, Q, R, constrained, bounds, osqp_settings)
