"""BallTable's observers: the detector (OpenCV image stage + PnP geometry stage), the
process and control models, and the observer pipelines (docs/spec/table_ball.md).

``OBSERVERS``: observer name -> pipeline factory, read by
:func:`observer_gym.estimation.default_pipeline`; the first is the default.
"""

from functools import partial

from observer_gym.estimation.ball_table.observer import BallTableObserver, BallTableObserverParams

OBSERVERS = {
    "kf": BallTableObserver,
    "kf-latency": partial(BallTableObserver, latency_aware=True),
}

__all__ = [
    "OBSERVERS",
    "BallTableObserver",
    "BallTableObserverParams",
]
