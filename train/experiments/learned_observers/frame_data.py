"""A learned detector's training data: frames and the perfect detector's report of each,
from one episode run twice in lockstep.

Each episode runs in ``obs_mode="rgb"`` and in ``obs_mode="measurements"`` with the same
options, seed and actions. The envs draw their randomness in the same order in every
mode, so both show the same world (checked at every step: the true states must be
equal); the rgb frame is the input, the measurement (its pixels without noise) the
label. The system's controller acts on the true state plus white noise whose std is
drawn per episode, so the scene is seen both where the controller keeps it and away from
there; every ``stride``-th frame is kept.
Latency and drops do not change a frame, so a system's ranges leave them out.

By default a step's sample is its observation (the frame) resized to the network's
input with its measurement's labels; a system whose network reads something else (the
delivered frames of several cameras, crops of them) gives ``samples_of``, which makes a
step's samples from both envs' observations and infos.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from observer_gym.controllers import make_controller
from observer_gym.estimation.learned.frame_detector import resized
from observer_gym.estimation.learned.frame_training import FrameDataset
from observer_gym.train.rl.randomize import draw_options, randomize_of_ranges

__all__ = ["collect_lockstep"]

Labels = Callable[[Any], tuple[np.ndarray, np.ndarray]]
# (rgb obs, rgb info, measurements obs, measurements info, generator) -> the step's samples,
# each (input, values, detected flags)
Samples = Callable[
    [Any, dict, Any, dict, np.random.Generator], list[tuple[np.ndarray, np.ndarray, np.ndarray]]
]


def _resized_samples(net_size_px: tuple[int, int], labels_of: Labels) -> Samples:
    """The default samples: the step's frame resized to ``net_size_px``, its labels."""

    def samples_of(frame: Any, info: dict, measurement: Any, measured_info: dict, rng: Any):
        return [(resized(frame, *net_size_px), *labels_of(measurement))]

    return samples_of


def collect_lockstep(
    env_id: str,
    episodes: int,
    seed: int,
    *,
    steps: int,
    stride: int,
    ranges: Mapping[str, tuple[float, float]],
    controller: str,
    noise_range: tuple[float, float],
    labels_of: Labels | None = None,
    net_size_px: tuple[int, int] | None = None,
    noise_scale: np.ndarray | None = None,
    env_kwargs: Mapping[str, Any] | None = None,
    samples_of: Samples | None = None,
) -> FrameDataset:
    """``episodes`` lockstep episodes of ``env_id`` (see the module docstring),
    reproducible from ``seed``.

    Args:
        ranges: env options drawn uniformly per episode.
        controller: the controller (``make_controller`` name) acting on the truth.
        noise_range: the action noise's std (times ``noise_scale``), drawn uniformly per
            episode.
        labels_of: a measurement -> (values, detected flags) (the default samples).
        net_size_px: the (width, height) the frames are resized to (the default samples).
        noise_scale: each action's scale of the noise (default 1: the action's units).
        env_kwargs: options every episode keeps.
        samples_of: a step's samples (see the module docstring), in place of
            ``labels_of`` and ``net_size_px``; it may draw from the generator it is given
            (the collection's, so the data stay reproducible from ``seed``).
    """
    if samples_of is None:
        if labels_of is None or net_size_px is None:
            raise ValueError("collect_lockstep needs samples_of, or labels_of and net_size_px")
        samples_of = _resized_samples(net_size_px, labels_of)

    rng = np.random.default_rng(seed)
    randomize = randomize_of_ranges(ranges)
    frames, values, detected, eps = [], [], [], []
    for episode in range(episodes):
        options: dict[str, Any] = draw_options(randomize, rng)
        options |= dict(env_kwargs or {})
        noise = float(rng.uniform(*noise_range))
        env_seed = int(rng.integers(2**31))
        rgb = gym.make(env_id, obs_mode="rgb", **options)
        measured = gym.make(env_id, obs_mode="measurements", **options)
        try:
            policy = make_controller(controller, measured)
            box = rgb.action_space
            if not isinstance(box, spaces.Box):
                raise ValueError(f"{env_id}'s action space is not a Box: {box}")
            scale = np.ones(box.shape) if noise_scale is None else np.asarray(noise_scale)
            noise_std = noise * scale
            frame, info = rgb.reset(seed=env_seed)
            measurement, measured_info = measured.reset(seed=env_seed)
            for step in range(steps):
                if step % stride == 0:
                    for x, v, d in samples_of(frame, info, measurement, measured_info, rng):
                        frames.append(x)
                        values.append(v)
                        detected.append(d)
                        eps.append(episode)
                planned, _ = policy.predict(info["state"], deterministic=True)
                action = np.clip(planned + rng.normal(0.0, noise_std), box.low, box.high)
                action = action.astype(np.float32)
                frame, _, terminated, truncated, info = rgb.step(action)
                measurement, _, _, _, measured_info = measured.step(action)
                if not np.array_equal(info["state"], measured_info["state"]):
                    raise RuntimeError(f"the lockstep envs diverged (episode {episode})")
                if terminated or truncated:
                    break
        finally:
            rgb.close()
            measured.close()
    return FrameDataset(
        np.array(frames), np.array(values), np.array(detected), np.array(eps, dtype=int)
    )
