"""TargetFollower's plant and its visual tracking controller (docs/spec/follower.md (13)).

``CONTROLLERS``: name -> design, read by :func:`observer_gym.controllers.make_controller`.
"""

from observer_gym.controllers.registry import ControllerDesign
from observer_gym.controllers.target_follower.plant import TargetFollowerPlant
from observer_gym.controllers.target_follower.vtc import VisualTrackingController

CONTROLLERS = {
    "vtc": ControllerDesign(
        VisualTrackingController,
        TargetFollowerPlant.from_env,
        "the paper's visual tracking controller u = B_i^-1 (K_g X_e - X_i^t') (13)",
    )
}

__all__ = ["CONTROLLERS", "TargetFollowerPlant", "VisualTrackingController"]
