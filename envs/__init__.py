"""observer-gym environments. Importing this package registers every env with Gymnasium.

Nothing here imports from estimation, controllers or train: they build on the envs'
public contract (layouts, camera geometry, info keys, the :data:`SYSTEMS` records), never
the other way round.
"""

from observer_gym.envs.registration import (
    SYSTEMS,
    System,
    register_envs,
    register_system,
    system_for_id,
    system_named,
    system_of,
    unregister_system,
)

register_envs()

# the package's own env ids (a system added by register_system is in SYSTEMS only)
ENV_IDS = tuple(system.env_id for system in SYSTEMS)

__all__ = [
    "ENV_IDS",
    "SYSTEMS",
    "System",
    "register_envs",
    "register_system",
    "system_for_id",
    "system_named",
    "system_of",
    "unregister_system",
]
