"""BallCatcher's observers: the ball detector, the ballistic model, the viewline Kalman
filter and the observer pipeline (docs/spec/catcher.md)."""

from observer_gym.estimation.ball_catcher.observer import BallCatcherObserver

__all__ = ["BallCatcherObserver"]
