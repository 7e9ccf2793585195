"""The reinforcement-learning algorithms an agent is trained with: their names
(stable-baselines3's, as ``--algo`` and ``ALGO:DIR`` take them) and, on use, their class
(which imports stable-baselines3 and PyTorch)."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from stable_baselines3.common.base_class import BaseAlgorithm

ALGOS = ("ppo", "sac", "td3")


def algorithm_class(algo: str) -> type[BaseAlgorithm]:
    """SB3's class for ``algo`` (ppo, sac, td3)."""
    from stable_baselines3 import PPO, SAC, TD3

    classes: dict[str, type[BaseAlgorithm]] = {"ppo": PPO, "sac": SAC, "td3": TD3}
    if algo not in classes:
        raise ValueError(f"unknown algo {algo!r}; allowed: {', '.join(ALGOS)}")
    return classes[algo]
