"""BallCatcher's plant and its intercept controller."""

from observer_gym.controllers.ball_catcher.intercept import InterceptController
from observer_gym.controllers.ball_catcher.plant import BallCatcherPlant

__all__ = ["BallCatcherPlant", "InterceptController"]
