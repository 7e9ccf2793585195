"""TargetFollower's plant and its visual tracking controller (docs/spec/follower.md (13))."""

from observer_gym.controllers.target_follower.plant import TargetFollowerPlant
from observer_gym.controllers.target_follower.vtc import VisualTrackingController

__all__ = ["TargetFollowerPlant", "VisualTrackingController"]
