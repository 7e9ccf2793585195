"""Gymnasium registration of every observer-gym environment."""

from __future__ import annotations

import gymnasium as gym

# id -> (entry point, max_episode_steps)
ENVS = {
    "observer_gym/BallTable-v0": ("observer_gym.envs.ball_table:BallTableEnv", 500),
    "observer_gym/BallCatcher-v0": ("observer_gym.envs.ball_catcher:BallCatcherEnv", 200),
    "observer_gym/TargetFollower-v0": (
        "observer_gym.envs.target_follower:TargetFollowerEnv",
        600,
    ),
}


def register_envs() -> None:
    for env_id, (entry_point, max_steps) in ENVS.items():
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=entry_point, max_episode_steps=max_steps)
