"""A ``measurements`` Dict observation as one flat Box, for an MLP policy."""

from __future__ import annotations

import gymnasium as gym
from gymnasium import spaces
from gymnasium.wrappers import FlattenObservation

from observer_gym.wrappers.frames import is_image


class FlatObservation(FlattenObservation):
    """A Dict observation (``obs_mode="measurements"``) as one flat float32 Box: Gymnasium's
    ``FlattenObservation``, refusing camera images, with the vector's layout.

    The entries follow one another in the Dict space's key order, which Gymnasium keeps
    sorted by name, each flattened in C order; a MultiBinary ``detected`` becomes 0.0 / 1.0
    and the bounds are the entries' bounds. ``layout`` maps each key to its slice of the
    vector. With the defaults:

    - BallTable-v0 (13,): ``ball_px`` [0:3] (u, v, radius), ``detected`` [3:5] (table,
      ball), ``table_corners_px`` [5:13] (u0, v0, ..., u3, v3);
    - BallCatcher-v1 with N cameras (4N,): ``detected`` [0:N], ``frame_age_s`` [N:2N],
      ``uv_px`` [2N:4N] (u_0, v_0, u_1, ...); with ``hole_measurements=True`` (6N,):
      ``detected``, ``frame_age_s``, ``hole_detected``, ``hole_uv_px``, ``uv_px``;
    - TargetFollower-v0 (4,): ``detected`` [0:1], ``target_px`` [1:4] (x_i, y_i, d_x).

    Args:
        env: an observer-gym env (or a wrapper of one) whose observation is a Dict of
            Boxes and MultiBinary flags, such as ``obs_mode="measurements"``.

    Raises:
        ValueError: the observation is not a Dict, or holds a camera image (use
            :class:`~observer_gym.wrappers.GrayFrameStack` for frames).

    Example:
        >>> import gymnasium as gym
        >>> from observer_gym.wrappers import FlatObservation
        >>> env = FlatObservation(
        ...     gym.make("observer_gym/TargetFollower-v0", obs_mode="measurements"))
        >>> env.observation_space.shape, env.observation_space.dtype
        ((4,), dtype('float32'))
        >>> env.layout
        {'detected': slice(0, 1, None), 'target_px': slice(1, 4, None)}
        >>> obs, info = env.reset(seed=0)
        >>> obs.shape
        (4,)
        >>> env.close()
    """

    def __init__(self, env: gym.Env) -> None:
        space = env.observation_space
        if not isinstance(space, spaces.Dict):
            raise ValueError(
                "FlatObservation flattens a Dict observation (an env made with "
                f"obs_mode='measurements'); got {space}"
            )
        images = [key for key, entry in space.spaces.items() if is_image(entry)]
        if images:
            raise ValueError(
                f"FlatObservation takes a Dict of measurements, not camera images "
                f"(entries {images}); for frames use observer_gym.wrappers.GrayFrameStack"
            )
        super().__init__(env)
        self.layout: dict[str, slice] = {}
        start = 0
        for key, entry in space.spaces.items():
            size = spaces.flatdim(entry)
            self.layout[key] = slice(start, start + size)
            start += size
