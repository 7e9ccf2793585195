"""The camera frames as the package's rgb agents read them: resized, grey, stacked."""

from __future__ import annotations

from collections.abc import Mapping
from copy import deepcopy
from typing import Any, cast

import cv2
import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.envs.registration import WrapperSpec
from gymnasium.wrappers import FrameStackObservation

SIZE_PX_RANGE = (8, 512)
STACK_SIZE_RANGE = (1, 16)


def is_image(space: gym.Space) -> bool:
    """Whether ``space`` is a camera image: a uint8 Box of shape (H, W, 3)."""
    return (
        isinstance(space, spaces.Box)
        and space.dtype == np.uint8
        and len(space.shape) == 3
        and space.shape[-1] == 3
    )


def _check_int(name: str, value: Any, bounds: tuple[int, int]) -> int:
    low, high = bounds
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an integer in [{low}, {high}], got {value!r}")
    if not low <= value <= high:
        raise ValueError(f"{name} must be an integer in [{low}, {high}], got {value!r}")
    return int(value)


class FrameImages(gym.ObservationWrapper, gym.utils.RecordConstructorArgs):
    """Every camera image of the observation resized to ``size_px`` x ``size_px`` and,
    with ``grayscale`` (the default), made grey.

    The observation is an env's ``obs_mode="rgb"`` one: a camera image ``Box(0, 255,
    (H, W, 3), uint8)`` (BallTable, TargetFollower) becomes ``Box(0, 255, (size_px,
    size_px), uint8)`` (``(size_px, size_px, 3)`` in colour); in a Dict (BallCatcher:
    ``camera_<c>`` per camera and ``frame_age_s``) each image entry is converted so and
    the other entries pass unchanged.

    The resize is OpenCV's area interpolation, as Gymnasium's ``ResizeObservation`` does
    it (the same pixels); grey is OpenCV's ``COLOR_RGB2GRAY`` (ITU-R BT.601 weights,
    rounded), on which the package's pixel encoders were trained. Written here rather than
    composed of Gymnasium's ``ResizeObservation`` and ``GrayscaleObservation``: those take
    a Box only (not BallCatcher's Dict), and Gymnasium's grey uses other weights.

    Args:
        env: an observer-gym env (or a wrapper of one) with ``obs_mode="rgb"``.
        size_px: the side of the square output image, an integer in [8, 512].
        grayscale: whether to convert each image to grey.

    Raises:
        ValueError: ``size_px`` is not an integer in [8, 512], ``grayscale`` is not a
            bool, or the observation holds no camera image (naming the space given).

    Example:
        >>> import gymnasium as gym
        >>> from observer_gym.wrappers import FrameImages
        >>> env = FrameImages(gym.make("observer_gym/BallTable-v0"), size_px=84)
        >>> env.observation_space
        Box(0, 255, (84, 84), uint8)
        >>> obs, info = env.reset(seed=0)
        >>> obs.shape, obs.dtype
        ((84, 84), dtype('uint8'))
        >>> env.close()
    """

    def __init__(self, env: gym.Env, size_px: int = 84, grayscale: bool = True) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, size_px=size_px, grayscale=grayscale)
        gym.ObservationWrapper.__init__(self, env)
        self.size_px = _check_int("FrameImages size_px", size_px, SIZE_PX_RANGE)
        if not isinstance(grayscale, bool):
            raise ValueError(f"FrameImages grayscale must be True or False, got {grayscale!r}")
        self.grayscale = grayscale
        shape = (self.size_px, self.size_px) if grayscale else (self.size_px, self.size_px, 3)
        image_space = spaces.Box(0, 255, shape, np.uint8)
        space = env.observation_space
        if is_image(space):
            self.observation_space = image_space
        elif isinstance(space, spaces.Dict) and any(map(is_image, space.spaces.values())):
            self.observation_space = spaces.Dict(
                {k: image_space if is_image(s) else s for k, s in space.spaces.items()}
            )
        else:
            raise ValueError(
                "FrameImages needs camera images (an env made with obs_mode='rgb': a Box "
                f"(H, W, 3) uint8 or a Dict holding such Boxes), got {space}"
            )

    def _image(self, image: np.ndarray) -> np.ndarray:
        side = (self.size_px, self.size_px)
        small = cv2.resize(image, side, interpolation=cv2.INTER_AREA)
        return cv2.cvtColor(small, cv2.COLOR_RGB2GRAY) if self.grayscale else small

    def observation(self, observation: Any) -> Any:
        if isinstance(observation, Mapping):
            space = cast(spaces.Dict, self.env.observation_space)  # a Dict for a Mapping
            return {k: self._image(v) if is_image(space[k]) else v for k, v in observation.items()}
        return self._image(observation)


class GrayFrameStack(FrameStackObservation):
    """The camera frames as the package's own rgb agents read them: each image resized
    to ``size_px`` x ``size_px`` and made grey (:class:`FrameImages`), and the last
    ``stack_size`` observations stacked by Gymnasium's ``FrameStackObservation`` (after a
    reset the first observation fills the stack).

    BallTable and TargetFollower give ``Box(0, 255, (stack_size, size_px, size_px),
    uint8)``, channel first: what SB3's ``CnnPolicy`` reads. BallCatcher gives a Dict:
    ``camera_<c>`` as that Box per camera and ``frame_age_s`` stacked to
    ``(stack_size, n_cameras)`` float32, for SB3's ``MultiInputPolicy``. The newest
    observation is the last along the first axis.

    Args:
        env: an observer-gym env (or a wrapper of one) with ``obs_mode="rgb"``.
        size_px: the side of each frame, an integer in [8, 512] (84 by default).
        stack_size: how many observations are stacked, an integer in [1, 16] (4).

    Raises:
        ValueError: ``size_px`` or ``stack_size`` out of range, or no camera image in
            the observation.

    Example:
        >>> import gymnasium as gym
        >>> import numpy as np
        >>> from observer_gym.wrappers import GrayFrameStack
        >>> env = GrayFrameStack(gym.make("observer_gym/BallTable-v0"))
        >>> env.observation_space
        Box(0, 255, (4, 84, 84), uint8)
        >>> obs, info = env.reset(seed=0)
        >>> obs, *_ = env.step(np.zeros(2, np.float32))
        >>> obs.shape, obs.dtype
        ((4, 84, 84), dtype('uint8'))
        >>> env.close()
    """

    def __init__(self, env: gym.Env, size_px: int = 84, stack_size: int = 4) -> None:
        # recorded first: FrameStackObservation would record only its own arguments
        gym.utils.RecordConstructorArgs.__init__(self, size_px=size_px, stack_size=stack_size)
        stack_size = _check_int("GrayFrameStack stack_size", stack_size, STACK_SIZE_RANGE)
        _check_int("GrayFrameStack size_px", size_px, SIZE_PX_RANGE)
        super().__init__(FrameImages(env, size_px=size_px, grayscale=True), stack_size)
        # The spec: the given env's with this wrapper, not with the FrameImages made here
        # too (gym.make(env.spec) builds this wrapper again, which makes that).
        given = env.spec
        if given is not None:
            spec = deepcopy(given)
            spec.additional_wrappers += (
                WrapperSpec(
                    name=self.class_name(),
                    entry_point=f"{type(self).__module__}:{type(self).__name__}",
                    kwargs=dict(self._saved_kwargs),
                ),
            )
            self._cached_spec = spec
