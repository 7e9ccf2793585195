"""BallCatcher's plant and its intercept controller.

``CONTROLLERS``: name -> design, read by :func:`observer_gym.controllers.make_controller`.
"""

from observer_gym.controllers.ball_catcher.intercept import InterceptController
from observer_gym.controllers.ball_catcher.plant import BallCatcherPlant
from observer_gym.controllers.registry import ControllerDesign

CONTROLLERS = {"intercept": ControllerDesign(InterceptController, BallCatcherPlant.from_env)}

__all__ = ["CONTROLLERS", "BallCatcherPlant", "InterceptController"]
