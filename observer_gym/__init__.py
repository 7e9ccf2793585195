"""observer-gym: Gymnasium environments in PyBullet controlled through what their cameras
see, with vision + Kalman-filter observers, control baselines and RL tools.

Importing ``observer_gym`` or any part of it (``observer_gym.envs``, ``.estimation``,
``.controllers``, ``.train``) registers every env with Gymnasium, so a process that only
unpickles an env factory (a ``SubprocVecEnv`` worker started with "spawn") finds the ids.
"""

from importlib import metadata

from observer_gym.envs.registration import register_envs

try:
    __version__ = metadata.version("observer-gym")
except metadata.PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0+unknown"

register_envs()

__all__ = ["__version__"]
