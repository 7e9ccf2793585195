"""TargetFollower's observers: the target detector, the image-state model, the visual
state estimator (STKF / KF) and the observer pipeline (docs/spec/follower.md)."""

from observer_gym.estimation.target_follower.observer import TargetFollowerObserver

__all__ = ["TargetFollowerObserver"]
