"""BallTable's controller design input (the plant) and default weights; the generic LQR,
MPC and PID in observer_gym.controllers are designed from it."""

from observer_gym.controllers.ball_table.plant import BallTablePlant
from observer_gym.controllers.ball_table.weights import ball_table_weights

__all__ = ["BallTablePlant", "ball_table_weights"]
