"""observer-gym: Gymnasium environments in PyBullet controlled through what their cameras
see, with vision + Kalman-filter observers, control baselines and RL tools.

The experiments of the ``observer-gym`` command are functions here: ``run``, ``compare``,
``sweep``, ``evaluate`` and ``record`` (:mod:`observer_gym.train.experiments.api`, imported
on first use),
taking
the package's names, import paths, factories or objects as observers and controllers.

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

API = ("run", "compare", "sweep", "evaluate", "record")


def __getattr__(name: str):
    """The experiment functions, imported when first used: ``import observer_gym`` stays
    light (Gymnasium and the env registry only)."""
    if name in API:
        from observer_gym.train.experiments import api

        return getattr(api, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["__version__", *API]
