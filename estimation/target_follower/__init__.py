"""TargetFollower's observers: the target detector, the image-state model, the visual
state estimator (STKF / KF) and the observer pipelines (docs/spec/follower.md).

``OBSERVERS``: observer name -> pipeline factory, read by
:func:`observer_gym.estimation.default_pipeline`; the first, the self-tuning filter, is
the default.

- ``stkf``, ``kf``: the visual state estimator fused when a frame is delivered
  (observer.py);
- ``stkf-latency``, ``kf-latency``: the same fused at each frame's capture time
  (latency.py);
- ``raw``: the detector alone, no filter (raw.py);
- ``ekf``: an extended Kalman filter on the target's world position and velocity with
  the pinhole camera as its measurement model (pixel_ekf.py);
- ``oracle-visible``: the true image state while the target is detected, predicted
  otherwise; reads ground truth, for analysis only (oracle_visible.py);
- ``learned``: a network trained on the simulator's truth, from the newest frames'
  detections to the estimate and its covariance, no filter (learned.py, weights
  learned.pt);
- ``learned-kf``: that network as ``kf``'s measurement model, its variance as R
  (learned_kf.py). Both read the perfect detector's measurements, or, from frames, the
  learned detector's (learned_detector.py, weights learned_detector.pt).
"""

from functools import partial

from observer_gym.estimation.target_follower.latency import LatencyAwareObserver
from observer_gym.estimation.target_follower.learned import LearnedObserver
from observer_gym.estimation.target_follower.learned_kf import LearnedKFObserver
from observer_gym.estimation.target_follower.observer import TargetFollowerObserver
from observer_gym.estimation.target_follower.oracle_visible import OracleVisibleObserver
from observer_gym.estimation.target_follower.pixel_ekf import PixelEKFObserver
from observer_gym.estimation.target_follower.raw import RawObserver

OBSERVERS = {
    "stkf": partial(TargetFollowerObserver, filter="stkf"),
    "kf": partial(TargetFollowerObserver, filter="kf"),
    "kf-latency": partial(LatencyAwareObserver, filter="kf"),
    "stkf-latency": partial(LatencyAwareObserver, filter="stkf"),
    "raw": RawObserver,
    "ekf": PixelEKFObserver,
    "oracle-visible": OracleVisibleObserver,
    "learned": LearnedObserver,
    "learned-kf": LearnedKFObserver,
}

__all__ = [
    "OBSERVERS",
    "LatencyAwareObserver",
    "LearnedKFObserver",
    "LearnedObserver",
    "OracleVisibleObserver",
    "PixelEKFObserver",
    "RawObserver",
    "TargetFollowerObserver",
]
