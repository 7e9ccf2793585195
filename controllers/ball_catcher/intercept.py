"""The intercept controller of BallCatcher-v1: move the hole to where the ball will cross
the box's front plane, re-planned every step (docs/spec/catcher.md, "The ball-catching robot").

Prediction: the drag-free flight of the estimated state (the model of the observer,
:class:`~observer_gym.estimation.ball_catcher.models.BallisticModel`): with the plane x = X,
t* = (X - p_x) / v_x and the crossing point c = p + v t* - (0, 0, g t*^2 / 2). Its
covariance follows to first order, Sigma_c = J P J^T with J = dc/d(p, v) (written out
in :func:`crossing_and_jacobian`); while the larger lateral standard deviation exceeds
``hold_std_m`` the box holds still instead of chasing an estimate that has not
converged yet (the covariance comes from the observer's ``info["estimate"]`` through
:meth:`InterceptController.observe_info`; without it the mean alone is used).

Motion: toward the target along the straight line, at the speed from which the robot
profile's deceleration still stops it at the target, sqrt(2 a d), capped by the profile's
speed and by a proportional term gain x d that ends the approach without overshoot in
discrete time.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from observer_gym.controllers.ball_catcher.plant import BallCatcherPlant
from observer_gym.controllers.base import StateFeedbackController, check_number
from observer_gym.envs.ball_catcher.layout import BALL_POS, BALL_VEL, BOX_POS
from observer_gym.envs.ball_catcher.throws import plane_crossing

__all__ = ["InterceptController", "crossing_and_jacobian"]


def crossing_and_jacobian(
    ball_state: np.ndarray, plane_x_m: float, gravity_mps2: float
) -> tuple[float, np.ndarray, np.ndarray] | None:
    """(t*, crossing point (3,), J (2, 6) = d(c_y, c_z)/d(p, v)) of a drag-free ball with
    state (p, v) crossing the plane x = ``plane_x_m`` moving toward -x; None if it does
    not approach the plane."""
    v = ball_state[3:6]
    crossing = plane_crossing(ball_state[:3], v, plane_x_m, gravity_mps2)
    if crossing is None:
        return None
    t, point = crossing
    vz_at_crossing = v[2] - gravity_mps2 * t
    dt_dpx, dt_dvx = -1.0 / v[0], -t / v[0]
    J = np.zeros((2, 6))
    J[0, 0], J[0, 1], J[0, 3], J[0, 4] = v[1] * dt_dpx, 1.0, v[1] * dt_dvx, t  # c_y
    J[1, 0], J[1, 2], J[1, 3], J[1, 5] = (  # c_z
        vz_at_crossing * dt_dpx,
        1.0,
        vz_at_crossing * dt_dvx,
        t,
    )
    return t, point, J


class InterceptController(StateFeedbackController):
    """Re-plans the box's motion toward the ball's predicted crossing every step.

    Args:
        plant: :class:`BallCatcherPlant` of the env.
        hold_std_m: hold still while the crossing point's larger lateral standard
            deviation (from the observer's covariance) exceeds this.
        brake_fraction: the fraction of the profile's acceleration planned for braking
            (margin for the arm's tracking lag).
        position_gain_per_s: the proportional cap on the speed near the target (1/s);
            default 1 / (3 dt).
        aim_depth_m: aim where the ball crosses the plane this far behind the front face
            (the middle of the front plate: its hole's axis midpoint).

    Numbers may be Python's or NumPy's; a bad option raises ``ValueError`` naming it and
    what it allows.
    """

    name = "intercept"

    def __init__(
        self,
        plant: BallCatcherPlant,
        hold_std_m: float = 0.05,
        brake_fraction: float = 0.8,
        position_gain_per_s: float | None = None,
        aim_depth_m: float = 0.005,
    ) -> None:
        if not isinstance(plant, BallCatcherPlant):
            raise ValueError(
                "InterceptController: plant must be a BallCatcherPlant "
                f"(BallCatcherPlant.from_env(env)), got {type(plant).__name__}"
            )
        low, high = plant.action_bounds
        super().__init__(plant.obs_dim, low, high)
        owner = "InterceptController"
        hold_std_m = check_number(owner, "hold_std_m", hold_std_m, low=0.0)
        aim_depth_m = check_number(owner, "aim_depth_m", aim_depth_m, low=0.0)
        brake_fraction = check_number(
            owner, "brake_fraction", brake_fraction, low=0.0, low_inclusive=False, high=1.0
        )
        gain = check_number(
            owner,
            "position_gain_per_s",
            position_gain_per_s,
            low=0.0,
            low_inclusive=False,
            allow_none=True,
        )
        gain = 1.0 / (3.0 * plant.dt_s) if gain is None else gain
        self.plant = plant
        self.hold_std_m = float(hold_std_m)
        self.brake_fraction = float(brake_fraction)
        self.position_gain_per_s = float(gain)
        self.aim_depth_m = float(aim_depth_m)
        self.profile = {
            "max_speed_mps": plant.max_speed_mps,
            "max_accel_mps2": plant.max_accel_mps2,
        }
        self._ball_covariance: np.ndarray | None = None
        self.last_crossing_std_m: float | None = None

    def reset(self) -> None:
        self._ball_covariance = None
        self.last_crossing_std_m = None

    def observe_info(self, info: Mapping[str, Any]) -> None:
        """Take the ball's covariance from an observer's ``info["estimate"]`` (used by the
        next single-observation :meth:`predict`); no estimate (the oracle): none."""
        estimate = info.get("estimate")
        self._ball_covariance = None if estimate is None else estimate["covariance"][:6, :6]

    def target(self, obs: np.ndarray, covariance: np.ndarray | None) -> np.ndarray:
        """Where the hole should go for one observation (12,)."""
        plant = self.plant
        box = obs[BOX_POS]
        ball = np.concatenate([obs[BALL_POS], obs[BALL_VEL]])
        crossing = crossing_and_jacobian(ball, box[0] - self.aim_depth_m, plant.gravity_mps2)
        self.last_crossing_std_m = None
        if crossing is None:
            return box.copy()  # the ball does not approach: stay
        _, point, J = crossing
        if covariance is not None:
            lateral = J @ covariance @ J.T
            self.last_crossing_std_m = float(np.sqrt(max(np.linalg.eigvalsh(lateral)[-1], 0.0)))
            if self.last_crossing_std_m > self.hold_std_m:
                return box.copy()
        target = np.array([plant.home_world[0], point[1], point[2]])
        return np.clip(target, plant.workspace_low_world, plant.workspace_high_world)

    def act(self, obs: np.ndarray, episode_start: np.ndarray) -> np.ndarray:
        single = len(obs) == 1
        actions = np.zeros((len(obs), 3))
        plant = self.plant
        for i, row in enumerate(obs):
            covariance = self._ball_covariance if single else None
            error = self.target(row, covariance) - row[BOX_POS]
            distance = float(np.linalg.norm(error))
            if distance < 1e-9:
                continue
            speed = min(
                plant.max_speed_mps,
                np.sqrt(2.0 * self.brake_fraction * plant.max_accel_mps2 * distance),
                self.position_gain_per_s * distance,
            )
            actions[i] = error * (speed / distance)
        return actions
