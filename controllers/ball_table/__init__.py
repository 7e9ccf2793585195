"""BallTable's controller design input (the plant) and default weights, and its
controllers: the generic LQR, MPC and PID of observer_gym.controllers designed from it
(the MPC with the table's bounds as options, :class:`BallTableMPC`).

``CONTROLLERS``: name -> design, read by :func:`observer_gym.controllers.make_controller`.
"""

from observer_gym.controllers.ball_table.mpc import BallTableMPC
from observer_gym.controllers.ball_table.plant import BallTablePlant
from observer_gym.controllers.ball_table.weights import ball_table_weights
from observer_gym.controllers.lqr import LQRController
from observer_gym.controllers.pid import PIDController
from observer_gym.controllers.registry import ControllerDesign

CONTROLLERS = {
    "lqr": ControllerDesign(
        LQRController,
        BallTablePlant.from_env,
        "LQR on the linearised ball-and-tilt model (python-control dlqr), tilt saturated",
    ),
    "mpc": ControllerDesign(
        BallTableMPC,
        BallTablePlant.from_env,
        "MPC with tilt, tilt-rate and ball bounds (sparse QP, OSQP); the LQR as terminal cost",
    ),
    "pid": ControllerDesign(
        PIDController, BallTablePlant.from_env, "PID per axis from the ball's position"
    ),
}

__all__ = ["CONTROLLERS", "BallTableMPC", "BallTablePlant", "ball_table_weights"]
