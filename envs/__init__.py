"""observer-gym environments. Importing this package registers every env with Gymnasium.

Nothing here imports from estimation, controllers or train: they build on the envs'
public contract (layouts, camera geometry, info keys, the :data:`SYSTEMS` records), never
the other way round.
"""

from observer_gym.envs.registration import (
    SYSTEMS,
    System,
    register_envs,
    system_for_id,
    system_named,
    system_of,
)

register_envs()

ENV_IDS = tuple(system.env_id for system in SYSTEMS)

__all__ = [
    "ENV_IDS",
    "SYSTEMS",
    "System",
    "register_envs",
    "system_for_id",
    "system_named",
    "system_of",
]
