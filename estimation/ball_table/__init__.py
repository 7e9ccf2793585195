"""BallTable's observers: the detector (OpenCV image stage + PnP geometry stage), the
process and control models, and the observer pipelines (docs/spec/table_ball.md).

``OBSERVERS``: observer name -> pipeline factory, read by
:func:`observer_gym.estimation.default_pipeline`; the first is the default.
"""

from functools import partial

from observer_gym.estimation.ball_table.learned import LearnedObserver
from observer_gym.estimation.ball_table.learned_kf import LearnedKFObserver
from observer_gym.estimation.ball_table.observer import BallTableObserver, BallTableObserverParams
from observer_gym.estimation.ball_table.oracle_visible import OracleVisibleObserver
from observer_gym.estimation.ball_table.pixel_ekf import PixelEKFObserver, PixelEKFParams
from observer_gym.estimation.ball_table.raw import RawObserver

OBSERVERS = {
    "kf": BallTableObserver,
    "kf-latency": partial(BallTableObserver, latency_aware=True),
    "ekf": PixelEKFObserver,
    "raw": RawObserver,
    "oracle-visible": OracleVisibleObserver,
    "learned": LearnedObserver,
    "learned-kf": LearnedKFObserver,
}

__all__ = [
    "OBSERVERS",
    "BallTableObserver",
    "BallTableObserverParams",
    "LearnedKFObserver",
    "LearnedObserver",
    "OracleVisibleObserver",
    "PixelEKFObserver",
    "PixelEKFParams",
    "RawObserver",
]
