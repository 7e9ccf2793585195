"""TargetFollower's observers: the target detector, the image-state model, the visual
state estimator (STKF / KF) and the observer pipeline (docs/spec/follower.md).

``OBSERVERS``: observer name -> pipeline factory, read by
:func:`observer_gym.estimation.default_pipeline`; the first, the self-tuning filter, is
the default.
"""

from functools import partial

from observer_gym.estimation.target_follower.observer import TargetFollowerObserver

OBSERVERS = {
    "stkf": partial(TargetFollowerObserver, filter="stkf"),
    "kf": partial(TargetFollowerObserver, filter="kf"),
}

__all__ = ["OBSERVERS", "TargetFollowerObserver"]
