"""The env an RL agent trains and is evaluated on.

``--obs`` picks what the agent reads, through the same observers as ``observer-gym run``:

- ``state``: the true state (observer "oracle");
- ``estimate``: the VisionObserver's estimate, which has the state's layout; it comes from
  perfect-detector measurements (observer "kf-measurements", no rendering) or from the
  camera frames (observer "kf"; TargetFollower: the self-tuning filter, "stkf-*"),
  chosen by ``--estimate-from``;
- ``rgb``: the camera frames themselves (observer "pixels"), preprocessed as
  :class:`ImageOptions` says: each camera image resized to ``size_px`` x ``size_px``
  (OpenCV, area interpolation), converted to grayscale, and the last ``frame_stack``
  observations stacked by Gymnasium's ``FrameStackObservation``, so a BallTable
  observation is a (4, 84, 84) uint8 image stack for SB3's CnnPolicy and a BallCatcher
  one a Dict of such stacks (and the stacked frame ages) for its MultiInputPolicy. With
  the image option ``encoder`` a pretrained CNN turns each frame into what it shows of
  the state (:mod:`observer_gym.train.rl.pixel_encoder`; BallTable: ball position and tilt)
  before stacking, and the policy is an MLP on the newest vector and the differences
  between consecutive ones, (frame_stack, 4).

With the hyperparameter ``features`` a state or estimate observation is replaced by (or
extended with) that feature set of :mod:`observer_gym.train.rl.features`. Training envs also
rescale the action space to [-1, 1] (Gymnasium's ``RescaleAction``), the range SB3's
Gaussian and squashed policies are built for; a loaded agent maps its
actions back to the env's units itself, so recorded actions are physical.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Mapping
from typing import Any, cast

import cv2
import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.wrappers import FrameStackObservation, RescaleAction

from observer_gym.train.cli.checks import agent_observer
from observer_gym.train.experiments.observer_env import make_env
from observer_gym.train.experiments.tasks import task_for
from observer_gym.train.rl.features import wrap_features

OBS_TYPES = ("state", "estimate", "rgb")
ESTIMATE_SOURCES = ("measurements", "rgb")


@dataclasses.dataclass(frozen=True)
class ImageOptions:
    """How camera frames are preprocessed for an agent trained with ``--obs rgb``."""

    size_px: int = 84
    grayscale: bool = True
    frame_stack: int = 4
    # a pretrained frame encoder (observer_gym.train.rl.pixel_encoder) between each frame and
    # the stack: a shipped encoder's name or a file; None: the policy reads image stacks
    encoder: str | None = None

    def __post_init__(self) -> None:
        if not (isinstance(self.size_px, int) and 8 <= self.size_px <= 512):
            raise ValueError(f"image size_px must be an integer in [8, 512], got {self.size_px!r}")
        if not (isinstance(self.frame_stack, int) and 1 <= self.frame_stack <= 16):
            raise ValueError(
                f"image frame_stack must be an integer in [1, 16], got {self.frame_stack!r}"
            )
        if not isinstance(self.grayscale, bool):
            raise ValueError(f"image grayscale must be true or false, got {self.grayscale!r}")
        if not (self.encoder is None or isinstance(self.encoder, str)):
            raise ValueError(
                f"image encoder must be a shipped encoder's name or a file, got {self.encoder!r}"
            )
        if self.frame_stack > 1 and not self.grayscale and self.encoder is None:
            raise ValueError(
                "image frame_stack > 1 needs grayscale: true (SB3's CnnPolicy reads a "
                "(stack, H, W) image; colour frames would stack to (stack, H, W, 3))"
            )


def observer_for(
    env_id: str, obs: str, estimate_from: str = "measurements", observer: str | None = None
) -> str:
    """The ``observer-gym run`` observer that feeds an agent trained with ``obs``:
    ``observer`` if given (``obs="estimate"`` only: any of the task's observers with a
    pipeline), else the task's ``ESTIMATE_OBSERVERS[estimate_from]`` for an estimate."""
    if obs not in OBS_TYPES:
        raise ValueError(f"unknown obs {obs!r}; allowed: {', '.join(OBS_TYPES)}")
    if estimate_from not in ESTIMATE_SOURCES:
        raise ValueError(
            f"unknown estimate_from {estimate_from!r}; allowed: {', '.join(ESTIMATE_SOURCES)}"
        )
    if observer is not None:
        # the light copy of the task's names checks it (the same message as the CLI's)
        return agent_observer(env_id, obs, estimate_from, observer)
    if obs == "state":
        return "oracle"
    if obs == "rgb":
        return "pixels"
    return task_for(env_id).ESTIMATE_OBSERVERS[estimate_from]


def _is_image(space: gym.Space) -> bool:
    return isinstance(space, spaces.Box) and space.dtype == np.uint8 and len(space.shape) == 3


class ResizeImages(gym.ObservationWrapper):
    """Every camera image of the observation (a Box image, or each image entry of a Dict)
    resized to ``size_px`` x ``size_px`` and optionally made grayscale (H, W); other Dict
    entries pass unchanged. Gymnasium's Resize/Grayscale wrappers take a Box only, and
    BallCatcher's frames come in a Dict, hence this wrapper over two OpenCV calls."""

    def __init__(self, env: gym.Env, size_px: int, grayscale: bool) -> None:
        super().__init__(env)
        self.size_px, self.grayscale = size_px, grayscale
        shape = (size_px, size_px) if grayscale else (size_px, size_px, 3)
        image_space = spaces.Box(0, 255, shape, np.uint8)
        space = env.observation_space
        if _is_image(space):
            self.observation_space = image_space
        elif isinstance(space, spaces.Dict) and any(map(_is_image, space.spaces.values())):
            self.observation_space = spaces.Dict(
                {k: image_space if _is_image(s) else s for k, s in space.spaces.items()}
            )
        else:
            raise ValueError(f"expected camera images to resize, got {space}")

    def _image(self, image: np.ndarray) -> np.ndarray:
        small = cv2.resize(image, (self.size_px, self.size_px), interpolation=cv2.INTER_AREA)
        return cv2.cvtColor(small, cv2.COLOR_RGB2GRAY) if self.grayscale else small

    def observation(self, observation: Any) -> Any:
        if isinstance(observation, Mapping):
            space = cast(spaces.Dict, self.env.observation_space)  # a Dict for a Mapping
            return {k: self._image(v) if _is_image(space[k]) else v for k, v in observation.items()}
        return self._image(observation)


def wrap_images(env: gym.Env, options: ImageOptions) -> gym.Env:
    """``env``'s camera frames resized and made grayscale as ``options`` says, each
    turned into a vector by its encoder if it names one
    (:class:`~observer_gym.train.rl.pixel_encoder.EncodedFrames`), and stacked (an encoder's
    stack as the newest vector and its differences,
    :class:`~observer_gym.train.rl.pixel_encoder.StackDifferences`)."""
    env = ResizeImages(env, options.size_px, options.grayscale)
    if options.encoder is not None:
        from observer_gym.train.rl.pixel_encoder import (
            EncodedFrames,
            StackDifferences,
            load_encoder,
        )

        env = EncodedFrames(env, load_encoder(options.encoder))
        if options.frame_stack > 1:
            env = StackDifferences(FrameStackObservation(env, options.frame_stack))
        return env
    if options.frame_stack > 1:
        env = FrameStackObservation(env, options.frame_stack)
    return env


def make_agent_env(
    env_id: str,
    obs: str,
    estimate_from: str = "measurements",
    env_kwargs: Mapping[str, Any] | None = None,
    image: Mapping[str, Any] | None = None,
    observer: str | None = None,
    features: str | None = None,
    randomize: Mapping[str, Mapping[str, Any]] | None = None,
) -> gym.Env:
    """The training env of an agent: ``observer_for(env_id, obs, estimate_from, observer)``'s env
    (``observer_gym.train.experiments.observer_env.make_env``), for ``rgb`` with
    :func:`wrap_images` (``image``:
    :class:`ImageOptions` fields), through the feature set ``features``, and the action
    space rescaled to [-1, 1]. A top-level function of plain arguments, so
    ``functools.partial`` of it pickles into spawned SubprocVecEnv workers.

    With ``randomize`` (a checked randomisation,
    :func:`observer_gym.train.rl.randomize.check_randomize`) the env is a
    :class:`~observer_gym.train.rl.randomize.RandomizedEnv` that builds this env anew at
    every reset with options drawn over ``env_kwargs``."""
    if randomize:
        from observer_gym.train.rl.randomize import RandomizedEnv

        fixed = dict(env_kwargs or {})
        make_inner = functools.partial(
            _drawn_agent_env, env_id, obs, estimate_from, fixed, image, observer, features
        )
        return RandomizedEnv(make_inner, env_id, randomize)
    env = make_env(env_id, observer_for(env_id, obs, estimate_from, observer), env_kwargs)
    return finish_agent_env(env, obs, image, features)


def _drawn_agent_env(
    env_id: str,
    obs: str,
    estimate_from: str,
    env_kwargs: Mapping[str, Any],
    image: Mapping[str, Any] | None,
    observer: str | None,
    features: str | None,
    drawn: Mapping[str, Any],
) -> gym.Env:
    """:func:`make_agent_env` with the options ``drawn`` over ``env_kwargs``."""
    return make_agent_env(
        env_id, obs, estimate_from, {**env_kwargs, **drawn}, image, observer, features
    )


def finish_agent_env(
    env: gym.Env,
    obs: str,
    image: Mapping[str, Any] | None = None,
    features: str | None = None,
) -> gym.Env:
    """The observer's ``env`` as an agent reading ``obs`` sees it: for ``rgb`` with
    :func:`wrap_images` (``image``: :class:`ImageOptions` fields), with the feature set
    ``features`` (:func:`~observer_gym.train.rl.features.wrap_features`), and the action space
    rescaled to [-1, 1]; ``env`` is closed if this fails."""
    try:
        if obs == "rgb":
            env = wrap_images(env, ImageOptions(**dict(image or {})))
        env = wrap_features(env, features)
        return RescaleAction(env, np.float32(-1.0), np.float32(1.0))
    except BaseException:
        env.close()
        raise


def to_env_action(action: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """An agent's action in [-1, 1] mapped to the env's [low, high] (RescaleAction's map)."""
    action = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
    return (low + (action + 1.0) * 0.5 * (high - low)).astype(np.float32)
