"""Controllers from outside the package, as the experiments drive them.

- :class:`CheckedController`: what an outside factory (an import path or an entry point,
  :mod:`observer_gym.train.core.entries`) returned, with every action it gives checked
  against
  the env's action space, so a wrong shape, NaN or a non-numeric action ends the episode
  with one line naming the entry, not somewhere inside the env.
- :class:`PolicyFile`: a stable-baselines3 model saved anywhere (``model.save(PATH)``),
  named ``ALGO:PATH.zip`` wherever a controller is taken. It reads the observation the
  env gives (the state, or an observer's estimate of it) and acts in the env's units.
  Loading a zip unpickles parts of it: load only files from a trusted source.
"""

from __future__ import annotations

import reprlib
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any, cast

import gymnasium as gym
import numpy as np

from observer_gym.extras import require_rl
from observer_gym.train.core import entries
from observer_gym.train.core.entry_guard import entry_fault, read_only


def checked_action(action: Any, space: gym.spaces.Box, who: str) -> np.ndarray:
    """``action`` as a float array of ``space``'s shape, clipped to its bounds as the env
    clips every action (so a finite but absurd action, 1e300, is the bound it is applied
    as, and is recorded so); ValueError naming ``who`` for anything else (another shape,
    complex, text, NaN or inf)."""
    try:
        array = np.asarray(action)
    except (TypeError, ValueError):
        array = None
    if array is None or array.dtype.kind not in "biuf" or array.shape != space.shape:
        raise ValueError(
            f"controller {who!r}: predict() must return (action, state) with an action of "
            f"real numbers of shape {space.shape}, got {reprlib.repr(action)}"
        )
    if not np.isfinite(array).all():
        raise ValueError(f"controller {who!r}: predict() returned a non-finite action {array}")
    return np.clip(array.astype(np.float64), space.low, space.high)


class CheckedController:
    """An outside controller with the protocol the experiments use (``name``, ``reset``,
    ``predict``, ``observe_info``), its actions checked by :func:`checked_action`, shown
    read-only copies of the observation and info
    (:func:`~observer_gym.train.core.entry_guard.read_only`), whatever it raises
    (``sys.exit`` too) one line naming it. Its other attributes (``failures``, design
    values) are the wrapped object's."""

    def __init__(self, plugin: entries.Plugin, env: gym.Env, options: Mapping[str, Any]):
        self.controller = entries.build(plugin, env, options)
        self.name = plugin.name
        self.entry = plugin.describe(options)
        self._space = cast(gym.spaces.Box, env.action_space)  # checked_action needs a Box

    def __getattr__(self, attribute: str) -> Any:  # only for attributes not set above
        return getattr(self.__dict__["controller"], attribute)

    def reset(self) -> None:
        reset = getattr(self.controller, "reset", None)
        if callable(reset):
            try:
                reset()
            except (Exception, SystemExit) as exc:
                raise entry_fault(f"controller {self.name!r}", "reset()", exc) from None

    def observe_info(self, info: Any) -> None:
        observe_info = getattr(self.controller, "observe_info", None)
        if callable(observe_info):
            try:
                observe_info(read_only(info))
            except (Exception, SystemExit) as exc:
                raise entry_fault(f"controller {self.name!r}", "observe_info()", exc) from None

    def predict(
        self,
        observation: Any,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        try:
            result = self.controller.predict(
                read_only(observation), state, episode_start, deterministic
            )
        except (Exception, SystemExit) as exc:  # its own fault: one line naming it
            raise entry_fault(f"controller {self.name!r}", "predict()", exc) from None
        if not (isinstance(result, tuple) and len(result) == 2):
            raise ValueError(
                f"controller {self.name!r}: predict() must return (action, state) as "
                f"stable-baselines3's does, got {reprlib.repr(result)}"
            )
        return checked_action(result[0], self._space, self.name), result[1]


def is_policy_file(path: Path) -> bool:
    """Whether ``path`` names a saved stable-baselines3 model (a file, not a run folder)."""
    return path.suffix == ".zip" or path.is_file()


def check_policy_file(name: str, path: Path) -> None:
    """ValueError unless ``path`` is a stable-baselines3 zip (``data`` and
    ``policy.pth`` inside); reads the archive's listing only. First, ExtraNotInstalled
    (:mod:`observer_gym.extras`) without stable-baselines3 and PyTorch to load it."""
    require_rl(f"policy {name!r}")  # stable-baselines3 and PyTorch load it
    if not path.is_file():
        raise ValueError(f"policy {name!r}: no file {path}")
    try:
        with zipfile.ZipFile(path) as archive:
            names = set(archive.namelist())
    except (zipfile.BadZipFile, OSError) as exc:
        raise ValueError(
            f"policy {name!r}: {path} is not a stable-baselines3 zip ({exc})"
        ) from None
    if not {"data", "policy.pth"} <= names:
        raise ValueError(
            f"policy {name!r}: {path} is not a stable-baselines3 model (no data and "
            "policy.pth inside)"
        )


class PolicyFile:
    """A stable-baselines3 model from ``ALGO:PATH.zip`` as a controller, on the CPU.

    Attributes:
        name: ``ALGO:PATH``; algo, run_dir (the file): recorded by the experiments.
    """

    def __init__(self, algo: str, path: Path, env: gym.Env):
        from observer_gym.train.core.algorithms import algorithm_class  # deferred: torch

        self.name, self.algo, self.run_dir = f"{algo}:{path}", algo, str(path)
        check_policy_file(self.name, path)
        try:
            self.model = algorithm_class(algo).load(path, device="cpu")
        except Exception as exc:  # a zip of another algorithm or a damaged one
            raise ValueError(
                f"policy {self.name!r}: {algo} cannot load it: {type(exc).__name__}: {exc}"
            ) from None
        model_shape = self.model.observation_space.shape
        env_shape = env.observation_space.shape
        if model_shape != env_shape:
            raise ValueError(
                f"policy {self.name!r} reads observations of shape {model_shape}, the env "
                f"gives {env_shape}"
            )
        if self.model.action_space.shape != env.action_space.shape:
            raise ValueError(
                f"policy {self.name!r} acts with shape {self.model.action_space.shape}, the "
                f"env takes {env.action_space.shape}"
            )
        self._space = cast(gym.spaces.Box, env.action_space)  # checked_action needs a Box

    def reset(self) -> None:
        """Nothing to reset: a stable-baselines3 policy here is feed-forward."""

    def predict(
        self,
        observation: Any,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        action, _ = self.model.predict(observation, deterministic=deterministic)
        return checked_action(action, self._space, self.name), state
