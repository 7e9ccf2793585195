"""BallCatcher's plant and its intercept controller.

``CONTROLLERS``: name -> design, read by :func:`observer_gym.controllers.make_controller`.
"""

from observer_gym.controllers.ball_catcher.intercept import InterceptController
from observer_gym.controllers.ball_catcher.plant import BallCatcherPlant
from observer_gym.controllers.registry import ControllerDesign

CONTROLLERS = {
    "intercept": ControllerDesign(
        InterceptController,
        BallCatcherPlant.from_env,
        "re-plans the box toward the ball's predicted crossing every step; holds while the "
        "crossing's standard deviation is large",
    )
}

__all__ = ["CONTROLLERS", "BallCatcherPlant", "InterceptController"]
