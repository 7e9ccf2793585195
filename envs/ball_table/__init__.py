"""BallTable-v0: a ball on a tilting table held by a robot arm (docs/spec/table_ball.md)."""

from observer_gym.envs.ball_table.config import BallTableConfig
from observer_gym.envs.ball_table.env import BallTableEnv
from observer_gym.envs.ball_table.layout import STATE_DIM, STATE_HIGH, STATE_NAMES, StateIndex

__all__ = [
    "STATE_DIM",
    "STATE_HIGH",
    "STATE_NAMES",
    "BallTableConfig",
    "BallTableEnv",
    "StateIndex",
]
