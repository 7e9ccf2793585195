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
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import gymnasium as gym
import numpy as np

__all__ = ["Controller", "StateFeedbackController", "unwrapped_env"]


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
    """

    name = "controller"

    def __init__(self, obs_dim: int, action_low: np.ndarray, action_high: np.ndarray) -> None:
        self.obs_dim = int(obs_dim)
        self.action_low = np.asarray(action_low, dtype=float)
        self.action_high = np.asarray(action_high, dtype=float)

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
        obs = np.asarray(observation, dtype=float)
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
        actions = np.clip(self.act(batch, starts), self.action_low, self.action_high)
        actions = actions.astype(np.float32)
        return (actions[0] if single else actions), state


def unwrapped_env(env: gym.Env, env_class: type, env_id: str, needed_by: str) -> gym.Env:
    """The base env under ``env``'s wrappers; ValueError unless it is an ``env_class``."""
    base = env.unwrapped
    if not isinstance(base, env_class):
        raise ValueError(f"{needed_by} needs a {env_id} env, got {type(base).__name__}")
    return base
