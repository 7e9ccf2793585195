"""BallTable's observers: the detector (OpenCV image stage + PnP geometry stage), the
process and control models, and the observer pipeline (docs/spec/table_ball.md)."""

from observer_gym.estimation.ball_table.observer import BallTableObserver, BallTableObserverParams

__all__ = ["BallTableObserver", "BallTableObserverParams"]
