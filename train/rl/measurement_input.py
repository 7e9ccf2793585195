"""What an agent trained with ``--obs measurements`` reads: the newest delivered frame's
perfect-detector report, unfiltered, as one vector, and optionally the last k of them.

:class:`MeasurementInput` turns the env's ``obs_mode="measurements"`` Dict into a float32
vector: the report flattened by :class:`~observer_gym.wrappers.FlatObservation` (the
detected flags as 0/1), then each camera's frame age, the time since the newest frame
it delivered was captured (s; :data:`NO_FRAME_AGE_S` before its first frame; an env
whose report already holds ``frame_age_s``, BallCatcher's, keeps its own), then what the
robot knows of itself without a camera, the same entries every observer reads from
``info`` (BallCatcher: the box's position and velocity, :data:`PROPRIOCEPTION`). With
``stack`` k > 1 the agent reads the last k such vectors, oldest first (Gymnasium's
``FrameStackObservation``, padded with the reset's; flattened), so it sees how old each
was and can difference them.

The observation is the newest frame *by capture time* (the env's own rule), so a frame
delivered out of order never replaces a newer one; with random latency the observation
can stay the same for several steps, and its age says so.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.wrappers import FlattenObservation, FrameStackObservation

from observer_gym.envs import system_of
from observer_gym.wrappers import FlatObservation

# age reported for a camera that has delivered nothing yet (BallCatcher's own value)
NO_FRAME_AGE_S = 10.0
# system name -> the info entries of the robot's own kinematics an agent reads, with their
# bound (the workspace's reach; VecNormalize scales them)
PROPRIOCEPTION: dict[str, tuple[tuple[str, int, float], ...]] = {
    "ball_catcher": (("box_pos_world_m", 3, 5.0), ("box_vel_world_mps", 3, 10.0)),
}
MAX_STACK = 16


class MeasurementInput(gym.Wrapper):
    """The report, frame ages and the robot's own kinematics as one vector (module
    docstring).

    Args:
        env: an observer-gym env made with ``obs_mode="measurements"``.

    Raises:
        ValueError: the env's observation is not a measurements Dict.
    """

    def __init__(self, env: gym.Env) -> None:
        flat = FlatObservation(env)
        super().__init__(flat)
        self.system = system_of(env)
        self.num_cameras = int(getattr(env.unwrapped, "num_cameras", 1))
        self.own_ages = "frame_age_s" not in flat.layout
        self.proprioception = PROPRIOCEPTION.get(self.system.name, ())
        base = flat.observation_space
        assert isinstance(base, spaces.Box)
        low, high = [base.low], [base.high]
        if self.own_ages:
            low.append(np.zeros(self.num_cameras, np.float32))
            high.append(np.full(self.num_cameras, NO_FRAME_AGE_S, np.float32))
        for _, size, bound in self.proprioception:
            low.append(np.full(size, -bound, np.float32))
            high.append(np.full(size, bound, np.float32))
        self.observation_space = spaces.Box(
            np.concatenate(low).astype(np.float32), np.concatenate(high).astype(np.float32)
        )
        self._newest_capture_s = np.full(self.num_cameras, -np.inf)

    def _vector(self, observation: np.ndarray, info: dict[str, Any]) -> np.ndarray:
        parts = [np.asarray(observation, np.float32)]
        if self.own_ages:
            for frame in info.get("frames", ()):
                camera = int(frame["camera_id"])
                self._newest_capture_s[camera] = max(
                    self._newest_capture_s[camera], float(frame["capture_time_s"])
                )
            # age = t_now - t_capture of the newest frame (by capture time) delivered so far
            ages = float(info["time_s"]) - self._newest_capture_s
            parts.append(np.minimum(ages, NO_FRAME_AGE_S).astype(np.float32))
        for key, size, bound in self.proprioception:
            value = np.asarray(info[key], np.float32).reshape(size)
            parts.append(np.clip(value, -bound, bound))
        return np.concatenate(parts)

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict[str, Any]]:
        observation, info = self.env.reset(**kwargs)
        self._newest_capture_s[:] = -np.inf
        return self._vector(observation, info), info

    def step(self, action: Any) -> tuple[np.ndarray, Any, bool, bool, dict[str, Any]]:
        observation, reward, terminated, truncated, info = self.env.step(action)
        return self._vector(observation, info), reward, terminated, truncated, info


def check_stack(stack: Any) -> int:
    """``stack`` as an int; ValueError unless it is an integer in [1, MAX_STACK]."""
    if isinstance(stack, float) and stack.is_integer():
        stack = int(stack)
    if isinstance(stack, bool) or not isinstance(stack, int) or not 1 <= stack <= MAX_STACK:
        raise ValueError(
            f"hyperparameter measurement_stack must be an integer in [1, {MAX_STACK}] "
            f"(how many of the newest measurements an agent reads), got {stack!r}"
        )
    return stack


def wrap_measurements(env: gym.Env, stack: int = 1) -> gym.Env:
    """``env`` (``obs_mode="measurements"``) as an agent trained with ``--obs
    measurements`` reads it: :class:`MeasurementInput`, and for ``stack`` > 1 the last
    ``stack`` of its vectors flattened, oldest first."""
    stack = check_stack(stack)
    env = MeasurementInput(env)
    if stack > 1:
        env = FlattenObservation(FrameStackObservation(env, stack))
    return env
