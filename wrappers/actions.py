"""The action space as [-1, 1], the range SB3's policies and env checker expect."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.wrappers import RescaleAction


class NormalizedAction(RescaleAction):
    """The env's action space ``Box(low, high)`` as ``Box(-1, 1)`` (float32, same shape):
    Gymnasium's ``RescaleAction``. An action ``a`` in [-1, 1] is applied as
    ``low + (a + 1) (high - low) / 2``; ``action(a)`` gives it.

    The env reports what it applied, in its own units and after its clipping, in
    ``info["applied_action"]``. An observer
    (:class:`~observer_gym.estimation.VisionObserver`) reads the applied action there,
    not from the action it is given, so it predicts with the env's units whether it
    wraps this wrapper (it is given the agent's [-1, 1] action) or is wrapped by it.

    Args:
        env: an env whose action space is a float Box with finite bounds, low < high.

    Raises:
        ValueError: the action space is not such a Box (naming it).

    Example:
        >>> import gymnasium as gym
        >>> import numpy as np
        >>> from observer_gym.wrappers import NormalizedAction
        >>> env = NormalizedAction(gym.make("observer_gym/BallTable-v0", obs_mode="state"))
        >>> env.action_space
        Box(-1.0, 1.0, (2,), float32)
        >>> _ = env.reset(seed=0)
        >>> *_, info = env.step(np.array([0.5, -1.0], np.float32))
        >>> info["applied_action"]  # radians: 0.5 and -1 of the env's +-0.1 rad
        array([ 0.05, -0.1 ])
        >>> env.close()
    """

    def __init__(self, env: gym.Env) -> None:
        space = env.action_space
        if not (
            isinstance(space, spaces.Box)
            and np.issubdtype(space.dtype, np.floating)
            and np.all(np.isfinite(space.low))
            and np.all(np.isfinite(space.high))
            and np.all(space.low < space.high)
        ):
            raise ValueError(
                "NormalizedAction needs a float Box action space with finite bounds, "
                f"low < high; got {space}"
            )
        gym.utils.RecordConstructorArgs.__init__(self)  # first: RescaleAction's are fixed
        super().__init__(env, np.float32(-1.0), np.float32(1.0))
