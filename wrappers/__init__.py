"""Gymnasium wrappers for using the envs from plain Gymnasium or stable-baselines3.

- :class:`GrayFrameStack`: the camera frames as the package's own rgb agents read them,
  each resized to 84 x 84, made grayscale and the last four stacked: a ``(4, 84, 84)``
  uint8 image for SB3's ``CnnPolicy`` (BallCatcher: a Dict of such stacks, for its
  ``MultiInputPolicy``). :class:`FrameImages` is its first step alone (resize and grey).
- :class:`FlatObservation`: a ``measurements`` Dict as one flat float32 Box, for an MLP
  policy; ``layout`` tells which slice of the vector holds which entry.
- :class:`NormalizedAction`: the action space as ``[-1, 1]`` (SB3's env checker's
  recommendation); the env still reports the action it applied, in its own units, in
  ``info["applied_action"]``, which is what an observer
  (:class:`~observer_gym.estimation.VisionObserver`) reads, below or above this wrapper.

Importing this package registers the envs with Gymnasium (as importing any part of
``observer_gym`` does). docs/training.md shows them with SB3.
"""

from observer_gym.wrappers.actions import NormalizedAction
from observer_gym.wrappers.flat import FlatObservation
from observer_gym.wrappers.frames import FrameImages, GrayFrameStack

__all__ = ["FlatObservation", "FrameImages", "GrayFrameStack", "NormalizedAction"]
