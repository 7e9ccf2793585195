"""The protocol every controller keeps, and the base class that implements it.

A controller maps an observation in the env's "state" layout (the true state, or an
observer's estimate of it) to an action, with stable-baselines3's call signature:

    action, state = controller.predict(obs, state=None, episode_start=None,
                                       deterministic=True)

so ``stable_baselines3.common.evaluation.evaluate_policy(controller, env)`` scores a
controller exactly as it scores a trained agent. ``obs`` is one observation (n,) or a
batch (n_envs, n) from a vector env; the action has the matching shape. Controllers with
memory (PID's integrator) keep it per batch row and clear a row where ``episode_start``
is True; ``reset()`` clears all of it.

:func:`check_number` is the check every controller option that is a number goes through:
finite, in range, a Python or NumPy number (``np.float32(0.1)``, ``np.int64(10)``), never a
bool, else ``ValueError`` naming the option and what is allowed.
"""

from __future__ import annotations

import numbers
import warnings
from typing import Any, Literal, Protocol, TypeVar, overload, runtime_checkable

import gymnasium as gym
import numpy as np

__all__ = ["Controller", "StateFeedbackController", "check_number", "unwrapped_env"]


@runtime_checkable
class Controller(Protocol):
    def reset(self) -> None: ...

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]: ...


class StateFeedbackController:
    """Base class: checks and batches observations; subclasses write :meth:`act`.

    ``obs_dim`` is the length of the observation, ``action_low`` / ``action_high`` the
    action bounds (every action returned lies within them). Subclasses implement
    ``act(obs_batch (b, obs_dim), episode_start (b,) bool) -> actions (b, action_dim)``.

    ``predict`` raises ``ValueError`` for an observation that is not an array of numbers of
    shape (obs_dim,) or (n_envs, obs_dim), or not finite. A finite observation so large that
    ``act`` overflows to a non-finite action gets the zero action for that row instead,
    counted in ``nonfinite_actions``, with a ``RuntimeWarning`` the first time.
    """

    name = "controller"

    def __init__(self, obs_dim: int, action_low: np.ndarray, action_high: np.ndarray) -> None:
        self.obs_dim = int(obs_dim)
        self.action_low = np.asarray(action_low, dtype=float)
        self.action_high = np.asarray(action_high, dtype=float)
        self.nonfinite_actions = 0  # rows whose action overflowed and were replaced by zero
        self._warned_nonfinite = False

    def reset(self) -> None:
        """Forget all memory (nothing for a static controller)."""

    def act(self, obs: np.ndarray, episode_start: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        """stable-baselines3's signature; ``state`` is passed through, ``deterministic`` is
        ignored (every controller here is deterministic)."""
        try:
            # only booleans, integers and floats: not complex (its imaginary part dropped),
            # strings, dates, objects (even of numbers) or masked arrays
            kind = np.asarray(observation).dtype.kind
            if kind not in "biuf" or isinstance(observation, np.ma.MaskedArray):
                raise TypeError(f"{type(observation).__name__} of dtype kind {kind!r}")
            obs = np.asarray(observation, dtype=float)
        except (TypeError, ValueError, OverflowError) as error:  # Overflow: 10**400
            raise ValueError(
                f"{type(self).__name__}.predict: observation must be an array of numbers of "
                f"shape ({self.obs_dim},) or (n_envs, {self.obs_dim}), got {observation!r} "
                f"({error})"
            ) from None
        single = obs.ndim == 1
        batch = obs.reshape(1, -1) if single else obs
        if batch.ndim != 2 or batch.shape[1] != self.obs_dim:
            raise ValueError(
                f"{type(self).__name__}.predict: observation has shape {obs.shape}, expected "
                f"({self.obs_dim},) or (n_envs, {self.obs_dim})"
            )
        if not np.all(np.isfinite(batch)):
            raise ValueError(
                f"{type(self).__name__}.predict: observation is not finite: {obs.tolist()}"
            )
        if episode_start is None:
            starts = np.zeros(len(batch), dtype=bool)
        else:
            starts = np.broadcast_to(
                np.asarray(episode_start, dtype=bool).reshape(-1), (len(batch),)
            )
        actions = np.asarray(self.act(batch, starts), dtype=float)
        bad = ~np.all(np.isfinite(actions), axis=1)
        if np.any(bad):  # overflow on huge (finite) observations: stop there
            actions[bad] = 0.0
            self.nonfinite_actions += int(np.count_nonzero(bad))
            if not self._warned_nonfinite:
                self._warned_nonfinite = True
                warnings.warn(
                    f"{type(self).__name__}.predict: the action for observation "
                    f"{batch[bad][0].tolist()} is not finite (overflow); returning the zero "
                    "action for it (later ones are counted in nonfinite_actions, not warned)",
                    RuntimeWarning,
                    stacklevel=2,
                )
        actions = np.clip(actions, self.action_low, self.action_high).astype(np.float32)
        return (actions[0] if single else actions), state


EnvT = TypeVar("EnvT", bound=gym.Env)


def unwrapped_env(env: gym.Env, env_class: type[EnvT], env_id: str, needed_by: str) -> EnvT:
    """The base env under ``env``'s wrappers; ValueError unless it is an ``env_class``."""
    base = env.unwrapped
    if not isinstance(base, env_class):
        raise ValueError(f"{needed_by} needs a {env_id} env, got {type(base).__name__}")
    return base


@overload
def check_number(
    owner: str,
    name: str,
    value: Any,
    *,
    low: float | None = None,
    high: float | None = None,
    low_inclusive: bool = True,
    integer: Literal[False] = False,
    allow_none: Literal[False] = False,
) -> float: ...
@overload
def check_number(
    owner: str,
    name: str,
    value: Any,
    *,
    low: float | None = None,
    high: float | None = None,
    low_inclusive: bool = True,
    integer: Literal[True],
    allow_none: Literal[False] = False,
) -> int: ...
@overload
def check_number(
    owner: str,
    name: str,
    value: Any,
    *,
    low: float | None = None,
    high: float | None = None,
    low_inclusive: bool = True,
    integer: bool = False,
    allow_none: bool = False,
) -> float | int | None: ...
def check_number(
    owner: str,
    name: str,
    value: Any,
    *,
    low: float | None = None,
    high: float | None = None,
    low_inclusive: bool = True,
    integer: bool = False,
    allow_none: bool = False,
) -> float | int | None:
    """``value`` as a float (an int with ``integer``), or ValueError naming ``owner``'s
    option ``name`` and what it allows: a finite number (Python's or NumPy's, bools
    excluded; with ``integer`` a whole one, e.g. 20 or 20.0) with ``low`` <= (or <, without
    ``low_inclusive``) value <= ``high``; None passes through with ``allow_none``."""
    if value is None and allow_none:
        return None
    if integer:
        kind = "an integer"
    else:
        kind = "a finite number"
    bounds = []
    if low is not None:
        bounds.append(f"{'>=' if low_inclusive else '>'} {low:g}")
    if high is not None:
        bounds.append(f"<= {high:g}")
    allowed = kind + (" " + " and ".join(bounds) if bounds else "")
    if allow_none:
        allowed = "None or " + allowed
    if isinstance(value, np.ndarray) and value.ndim == 0:
        value = value[()]
    number = isinstance(value, numbers.Real) and not isinstance(value, bool | np.bool_)
    try:
        ok = number and bool(np.isfinite(float(value)))
    except OverflowError:  # an int beyond float's range
        ok = False
    if ok and integer:
        ok = float(value) == int(value)
    if ok and low is not None:
        ok = float(value) >= low if low_inclusive else float(value) > low
    if ok and high is not None:
        ok = float(value) <= high
    if not ok:
        raise ValueError(f"{owner}: {name} = {value!r}, must be {allowed}")
    return int(value) if integer else float(value)
