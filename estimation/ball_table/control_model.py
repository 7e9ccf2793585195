"""The BallTable plant for control: ball and arm, linearised about the level table.

The same pieces the BallTable observer filters with (estimation/ball_table/observer.py):
the rolling ball's in-plane gravity acceleration a = -(5/7) g Z_gnd,table[x, y]
(:meth:`RollingBallModel.gravity_acceleration` of :func:`up_in_table`, docs/spec/table_ball.md
"Dynamics and estimator") and the arm's first-order tilt lag from the commanded tilt
(:class:`TiltLagModel`, time constant from the env's joint gain). Linearised at zero tilt,
per table axis:

    p' = v,   v' = G theta,   theta' = (u - theta) / tau

with G = da/dtheta (2, 2) taken from those functions, not written down: it comes out as
(5/7) g [[0, 1], [-1, 0]], so tilt_y rolls the ball along +x and tilt_x along -y.

State x = (p_x, p_y, v_x, v_y, theta_x, theta_y): the first six entries of the env's
"state" layout (the last two, the tilt rates, follow from theta and u). Input u: the
commanded tilt (rad), the env's action.
"""

from __future__ import annotations

import numpy as np

from observer_gym.envs.ball_table.geometry import up_in_table
from observer_gym.estimation.ball_table.models import RollingBallModel, TiltLagModel
from observer_gym.estimation.models import LinearModel

__all__ = ["BallTableControlModel", "tilt_to_acceleration"]

_JACOBIAN_STEP_RAD = 1e-6


def tilt_to_acceleration() -> np.ndarray:
    """G = da/dtheta at the level table (2, 2), (m/s^2)/rad: central differences of the
    estimator's own gravity model, exact to ~1e-10 relative (its second derivative is 0
    at zero tilt)."""
    G = np.empty((2, 2))
    for j in range(2):
        step = np.zeros(2)
        step[j] = _JACOBIAN_STEP_RAD
        a_plus = RollingBallModel.gravity_acceleration(up_in_table(*step))
        a_minus = RollingBallModel.gravity_acceleration(up_in_table(*(-step)))
        G[:, j] = (a_plus - a_minus) / (2.0 * _JACOBIAN_STEP_RAD)
    return G


class BallTableControlModel(LinearModel):
    """x' = A x + B u (module docstring); ``matrices(dt_s)`` gives the exact zero-order-hold
    (Phi, Gamma, Q) with Q = 0 (a nominal model: no process noise)."""

    n = 6
    m = 2

    def __init__(self, tilt_model: TiltLagModel) -> None:
        if tilt_model.dim != 2:
            raise ValueError(f"BallTableControlModel: tilt model has dim {tilt_model.dim}, need 2")
        self.tilt_model = tilt_model
        self.tau_s = tilt_model.tau_s
        self.G = tilt_to_acceleration()
        self.G.flags.writeable = False

    @classmethod
    def from_config(cls, config) -> BallTableControlModel:
        """The model of an env made with this BallTableConfig (its arm gain and physics
        step set the tilt lag)."""
        lag = TiltLagModel.from_arm(config.arm_position_gain, config.physics_dt_s, 0.0)
        return cls(lag)

    def continuous(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(A, B, G_noise, Qc) with a zero noise intensity."""
        A = np.zeros((6, 6))
        A[0:2, 2:4] = np.eye(2)  # p' = v
        A[2:4, 4:6] = self.G  # v' = G theta
        A[4:6, 4:6] = -np.eye(2) / self.tau_s  # theta' = (u - theta) / tau
        B = np.zeros((6, 2))
        B[4:6, :] = np.eye(2) / self.tau_s
        return A, B, np.zeros((6, 1)), np.zeros((1, 1))
