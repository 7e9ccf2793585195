"""Controllers with stable-baselines3's ``predict`` signature: the generic LQR, MPC (OSQP)
and PID, designed from any system's plant (the protocols of ``controllers/plant.py``;
BallTable's plant provides them), the intercept planner (BallCatcher), the visual
tracking controller (TargetFollower).

``make_controller(name, env, **options)`` designs one of the env's system's controllers
(``controllers_for(env_id)``: the ``CONTROLLERS`` of ``observer_gym.controllers.<system>``)
from the nominal model in observer_gym.estimation; ``evaluate_policy(controller, env)``
scores it like an SB3 agent.
"""

from observer_gym.controllers.ball_catcher.intercept import InterceptController
from observer_gym.controllers.ball_catcher.plant import BallCatcherPlant
from observer_gym.controllers.ball_table.mpc import BallTableMPC
from observer_gym.controllers.ball_table.plant import BallTablePlant
from observer_gym.controllers.ball_table.weights import ball_table_weights
from observer_gym.controllers.base import Controller, StateFeedbackController
from observer_gym.controllers.lqr import LQRController
from observer_gym.controllers.mpc import MPCController
from observer_gym.controllers.pid import PIDController
from observer_gym.controllers.plant import (
    AxesPlant,
    ConstrainedPlant,
    DoubleIntegratorAxes,
    LinearPlant,
    StageBound,
)
from observer_gym.controllers.registry import (
    ControllerDesign,
    check_controller_fits,
    controllers_for,
    controllers_of,
    design_controller,
    make_controller,
)
from observer_gym.controllers.target_follower.plant import TargetFollowerPlant
from observer_gym.controllers.target_follower.vtc import VisualTrackingController
from observer_gym.controllers.weights import check_weights

__all__ = [
    "AxesPlant",
    "BallCatcherPlant",
    "BallTableMPC",
    "BallTablePlant",
    "ConstrainedPlant",
    "Controller",
    "ControllerDesign",
    "DoubleIntegratorAxes",
    "InterceptController",
    "LQRController",
    "LinearPlant",
    "MPCController",
    "PIDController",
    "StageBound",
    "StateFeedbackController",
    "TargetFollowerPlant",
    "VisualTrackingController",
    "ball_table_weights",
    "check_controller_fits",
    "check_weights",
    "controllers_for",
    "controllers_of",
    "design_controller",
    "make_controller",
]
