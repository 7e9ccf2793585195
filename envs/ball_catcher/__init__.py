"""``observer_gym/BallCatcher-v1``: an arm carries a box with a hole; a ball is thrown at
it; unsynchronised cameras watch (docs/spec/catcher.md)."""

from observer_gym.envs.ball_catcher.config import (
    CAMERA_PRESETS,
    ROBOT_PROFILES,
    BallCatcherConfig,
    RobotProfile,
)
from observer_gym.envs.ball_catcher.env import MISS_REASONS, BallCatcherEnv
from observer_gym.envs.ball_catcher.layout import STATE_DIM, STATE_NAMES, StateIndex

__all__ = [
    "CAMERA_PRESETS",
    "MISS_REASONS",
    "ROBOT_PROFILES",
    "STATE_DIM",
    "STATE_NAMES",
    "BallCatcherConfig",
    "BallCatcherEnv",
    "RobotProfile",
    "StateIndex",
]
