"""observer-gym environments. Importing this package registers every env with Gymnasium.

Nothing here imports from estimation, controllers or train: they build on the envs'
public contract (layouts, camera geometry, info keys), never the other way round.
"""

from observer_gym.envs.registration import ENVS, register_envs

register_envs()

ENV_IDS = tuple(ENVS)

__all__ = ["ENV_IDS", "register_envs"]
