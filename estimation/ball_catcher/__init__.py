"""BallCatcher's observers: the ball detector, the ballistic models, the viewline Kalman
filter and the observer pipelines (docs/spec/catcher.md).

``OBSERVERS``: observer name -> pipeline factory, read by
:func:`observer_gym.estimation.default_pipeline`; the first is the default.
``ENV_OPTIONS``: the env options an observer needs (read by
:func:`observer_gym.estimation.observer.env_options_of`; the experiments set them).

- ``kf``: the viewline Kalman filter (:class:`BallCatcherObserver`).
- ``kf-latency``: the same pipeline as ``kf``, registered under both names: ``kf``
  already fuses every frame at its capture time (late and out-of-order frames by exact
  re-filtering) and reports the prediction to the step's time, the time the next action
  is applied (see :mod:`~observer_gym.estimation.ball_catcher.observer`), so there is no
  latency gap for a second pipeline to close.
- ``kf-at-delivery``: ``kf`` fusing each frame when it is delivered, as if captured then
  (``fuse_at="delivery"``): no latency handling, the reference that shows what fusing at
  the capture time buys.
- ``raw``: triangulation of the two newest detections, no filter (:class:`RawObserver`).
- ``ekf``: an iterated EKF on the pixels through each frame's pinhole model, fused at
  capture time (:class:`PixelEKFObserver`).
- ``oracle-visible``: ground truth while the ball is detected, predicted otherwise; reads
  the truth, for analysis only (:class:`OracleVisibleObserver`).
- ``learned``: a network trained on the simulator's truth maps the newest frames'
  detections of both cameras to the ball's state and a diagonal covariance, no filter
  (:class:`LearnedObserver`, estimation/ball_catcher/learned.py; from frames through the
  learned detector, estimation/ball_catcher/learned_detector.py, or from measurements).
- ``selfcal``: the pixel EKF with each camera's declared-uncertain calibration parameters
  as states it estimates from the frames (:class:`SelfCalibratingObserver`,
  estimation/ball_catcher/self_calibrating.py).
- ``endpoint``: ``selfcal`` with the box's hole as a landmark of known position (the
  robot's kinematics): a camera that sees both the ball and the hole has its error
  measured by the hole, so the ball relative to the hole is nearly free of it; needs the
  env's ``hole_measurements=True`` (measurements mode) (:class:`EndpointObserver`).
- ``learned-kf``: that network as the viewline filter's measurement model, a 3-D position
  measurement in place of the viewline rows (:class:`LearnedKFObserver`,
  estimation/ball_catcher/learned_kf.py; from frames or measurements, as ``learned``).
"""

import functools

from observer_gym.estimation.ball_catcher.learned import LearnedObserver
from observer_gym.estimation.ball_catcher.learned_kf import LearnedKFObserver
from observer_gym.estimation.ball_catcher.observer import BallCatcherObserver
from observer_gym.estimation.ball_catcher.oracle_visible import OracleVisibleObserver
from observer_gym.estimation.ball_catcher.pixel_ekf import PixelEKFObserver
from observer_gym.estimation.ball_catcher.raw import RawObserver
from observer_gym.estimation.ball_catcher.self_calibrating import (
    EndpointObserver,
    SelfCalibratingObserver,
)

OBSERVERS = {
    "kf": BallCatcherObserver,
    "kf-latency": BallCatcherObserver,  # kf is already latency-aware (see above)
    "kf-at-delivery": functools.partial(BallCatcherObserver, fuse_at="delivery"),
    "raw": RawObserver,
    "ekf": PixelEKFObserver,
    "oracle-visible": OracleVisibleObserver,
    "selfcal": SelfCalibratingObserver,
    "endpoint": EndpointObserver,
    "learned": LearnedObserver,
    "learned-kf": LearnedKFObserver,
}

# the env options an observer needs to run
ENV_OPTIONS = {"endpoint": {"hole_measurements": True}}

__all__ = [
    "ENV_OPTIONS",
    "OBSERVERS",
    "BallCatcherObserver",
    "EndpointObserver",
    "LearnedKFObserver",
    "LearnedObserver",
    "OracleVisibleObserver",
    "PixelEKFObserver",
    "RawObserver",
    "SelfCalibratingObserver",
]
