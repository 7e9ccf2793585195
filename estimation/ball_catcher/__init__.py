"""BallCatcher's observers: the ball detector, the ballistic model, the viewline Kalman
filter and the observer pipeline (docs/spec/catcher.md).

``OBSERVERS``: observer name -> pipeline factory, read by
:func:`observer_gym.estimation.default_pipeline`; the first is the default.
"""

from observer_gym.estimation.ball_catcher.observer import BallCatcherObserver

OBSERVERS = {"kf": BallCatcherObserver}

__all__ = ["OBSERVERS", "BallCatcherObserver"]
