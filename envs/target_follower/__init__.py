"""``observer_gym/TargetFollower-v0``: a wheeled robot with a tilt camera follows a target."""

from observer_gym.envs.target_follower.config import TargetFollowerConfig
from observer_gym.envs.target_follower.env import TargetFollowerEnv
from observer_gym.envs.target_follower.layout import (
    APPLIED,
    DETECTED,
    IMAGE,
    IMAGE_RATE,
    STATE_DIM,
    STATE_NAMES,
    TARGET_PX,
    StateIndex,
)

__all__ = [
    "APPLIED",
    "DETECTED",
    "IMAGE",
    "IMAGE_RATE",
    "STATE_DIM",
    "STATE_NAMES",
    "TARGET_PX",
    "StateIndex",
    "TargetFollowerConfig",
    "TargetFollowerEnv",
]
