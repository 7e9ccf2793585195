"""The env an RL agent trains and is evaluated on.

``--obs`` picks what the agent reads, through the same observers as ``observer-gym run``:

- ``state``: the true state (observer "oracle");
- ``estimate``: the VisionObserver's estimate, which has the state's layout; it comes from
  perfect-detector measurements (observer "kf-measurements", no rendering) or from the
  camera frames (observer "kf"; TargetFollower: the self-tuning filter, "stkf-*"),
  chosen by ``--estimate-from``;
- ``measurements``: the newest delivered frame's perfect-detector report, unfiltered
  (observer "detections"), with each camera's frame age and the robot's own kinematics,
  and with the hyperparameter ``measurement_stack`` k the last k of them
  (:mod:`observer_gym.train.rl.measurement_input`);
- ``rgb``: the camera frames themselves (observer "pixels"), preprocessed as
  :class:`ImageOptions` says: each camera image resized to ``size_px`` x ``size_px``
  (OpenCV, area interpolation), converted to grayscale, and the last ``frame_stack``
  observations stacked by Gymnasium's ``FrameStackObservation`` (the public
  :class:`~observer_gym.wrappers.GrayFrameStack`), so a BallTable
  observation is a (4, 84, 84) uint8 image stack for SB3's CnnPolicy and a BallCatcher
  one a Dict of such stacks (and the stacked frame ages) for its MultiInputPolicy. With
  the image option ``encoder`` a pretrained CNN turns each frame into what it shows of
  the state (:mod:`observer_gym.train.rl.pixel_encoder`; BallTable: ball position and tilt)
  before stacking, and the policy is an MLP on the newest vector and the differences
  between consecutive ones, (frame_stack, 4).

With the hyperparameter ``features`` a state or estimate observation is replaced by (or
extended with) that feature set of :mod:`observer_gym.train.rl.features`. Training envs also
rescale the action space to [-1, 1] (:class:`~observer_gym.wrappers.NormalizedAction`,
Gymnasium's ``RescaleAction``), the range SB3's
Gaussian and squashed policies are built for; a loaded agent maps its
actions back to the env's units itself, so recorded actions are physical.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.wrappers import FrameStackObservation

from observer_gym.envs import system_for_id
from observer_gym.train.core.checks import agent_observer
from observer_gym.train.core.observer_env import make_env, resolve_observer
from observer_gym.train.core.tasks import task_of
from observer_gym.train.rl.features import wrap_features
from observer_gym.train.rl.measurement_input import wrap_measurements
from observer_gym.wrappers import FrameImages, GrayFrameStack, NormalizedAction

OBS_TYPES = ("state", "estimate", "rgb", "measurements")
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
    if obs == "measurements":
        return "detections"
    return task_of(system_for_id(env_id)).ESTIMATE_OBSERVERS[estimate_from]


def wrap_images(env: gym.Env, options: ImageOptions) -> gym.Env:
    """``env``'s camera frames resized and made grayscale as ``options`` says (the public
    :class:`~observer_gym.wrappers.FrameImages`; by default, 84 x 84 grey, four stacked:
    :class:`~observer_gym.wrappers.GrayFrameStack`), each turned into a vector by its
    encoder if it names one
    (:class:`~observer_gym.train.rl.pixel_encoder.EncodedFrames`), and stacked (an encoder's
    stack as the newest vector and its differences,
    :class:`~observer_gym.train.rl.pixel_encoder.StackDifferences`)."""
    if options.encoder is None and options.grayscale and options.frame_stack > 1:
        return GrayFrameStack(env, size_px=options.size_px, stack_size=options.frame_stack)
    env = FrameImages(env, size_px=options.size_px, grayscale=options.grayscale)
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
    measurement_stack: int = 1,
) -> gym.Env:
    """The training env of an agent: ``observer_for(env_id, obs, estimate_from, observer)``'s env
    (``observer_gym.train.core.observer_env.make_env``), for ``rgb`` with
    :func:`wrap_images` (``image``:
    :class:`ImageOptions` fields), for ``measurements`` with
    :func:`~observer_gym.train.rl.measurement_input.wrap_measurements` (the last
    ``measurement_stack``), through the feature set ``features``, and the action
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
            _drawn_agent_env,
            env_id,
            obs,
            estimate_from,
            fixed,
            image,
            observer,
            features,
            measurement_stack,
        )
        return RandomizedEnv(make_inner, env_id, randomize)
    feeding = observer_for(env_id, obs, estimate_from, observer)
    system = system_for_id(env_id)
    env = make_env(system, resolve_observer(system, feeding), env_kwargs)
    return finish_agent_env(env, obs, image, features, measurement_stack)


def _drawn_agent_env(
    env_id: str,
    obs: str,
    estimate_from: str,
    env_kwargs: Mapping[str, Any],
    image: Mapping[str, Any] | None,
    observer: str | None,
    features: str | None,
    measurement_stack: int,
    drawn: Mapping[str, Any],
) -> gym.Env:
    """:func:`make_agent_env` with the options ``drawn`` over ``env_kwargs``."""
    return make_agent_env(
        env_id,
        obs,
        estimate_from,
        {**env_kwargs, **drawn},
        image,
        observer,
        features,
        measurement_stack=measurement_stack,
    )


def finish_agent_env(
    env: gym.Env,
    obs: str,
    image: Mapping[str, Any] | None = None,
    features: str | None = None,
    measurement_stack: int = 1,
) -> gym.Env:
    """The observer's ``env`` as an agent reading ``obs`` sees it: for ``rgb`` with
    :func:`wrap_images` (``image``: :class:`ImageOptions` fields), for ``measurements``
    with :func:`~observer_gym.train.rl.measurement_input.wrap_measurements` (the last
    ``measurement_stack``), with the feature set
    ``features`` (:func:`~observer_gym.train.rl.features.wrap_features`), and the action space
    rescaled to [-1, 1]; ``env`` is closed if this fails."""
    try:
        if obs == "rgb":
            env = wrap_images(env, ImageOptions(**dict(image or {})))
        elif obs == "measurements":
            env = wrap_measurements(env, measurement_stack)
        env = wrap_features(env, features)
        return NormalizedAction(env)
    except BaseException:
        env.close()
        raise


def to_env_action(action: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """An agent's action in [-1, 1] mapped to the env's [low, high] (RescaleAction's map)."""
    action = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
    return (low + (action + 1.0) * 0.5 * (high - low)).astype(np.float32)
