"""How the frames of a delay level arrive, measured from the env's own delivery records.

A delivered frame is *out of order* when its camera has already delivered a frame
captured later: it arrives behind a newer one, so the newest observation (the env's
newest frame by capture time) does not change with it, and a filter that fuses frames as
they come sees time run backwards. The fraction is counted over every frame delivered
(``info["frames"]``: camera, capture and delivery times), with the action held at the
middle of its range (when a frame arrives does not depend on the action).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import gymnasium as gym
import numpy as np

from observer_gym.envs import system_for_id


class Delivery(NamedTuple):
    """What one delay level did to the frames over some episodes."""

    episodes: int
    steps: int
    frames_delivered: int
    frames_out_of_order: int
    out_of_order_fraction: float  # of the frames delivered
    newest_age_mean_s: float  # the newest frame's age at a step (capture to now), mean
    newest_age_max_s: float


def measure_delivery(
    env_id: str, env_kwargs: dict[str, Any], min_frames: int, seed: int
) -> Delivery:
    """Run episodes of ``env_id`` (measurements, ``env_kwargs``; episode i resets with
    ``seed + i``) until at least ``min_frames`` frames were delivered, and count how they
    arrived (module docstring)."""
    system = system_for_id(env_id)
    env = gym.make(system.env_id, obs_mode="measurements", **env_kwargs)
    delivered = out_of_order = steps = episodes = 0
    ages: list[float] = []
    try:
        space = env.action_space
        assert isinstance(space, gym.spaces.Box)
        action = ((space.low + space.high) / 2.0).astype(space.dtype)
        while delivered < min_frames:
            _, info = env.reset(seed=seed + episodes)
            episodes += 1
            newest: dict[int, float] = {}
            done = False
            while not done:
                _, _, terminated, truncated, info = env.step(action)
                steps += 1
                for frame in info["frames"]:  # this step's, in capture order
                    camera, capture_s = int(frame["camera_id"]), float(frame["capture_time_s"])
                    delivered += 1
                    if capture_s < newest.get(camera, -np.inf):
                        out_of_order += 1
                    newest[camera] = max(newest.get(camera, -np.inf), capture_s)
                if newest:
                    # the observation's age: now - capture time of the newest frame
                    ages.append(float(info["time_s"]) - max(newest.values()))
                done = terminated or truncated
    finally:
        env.close()
    return Delivery(
        episodes=episodes,
        steps=steps,
        frames_delivered=delivered,
        frames_out_of_order=out_of_order,
        out_of_order_fraction=out_of_order / max(delivered, 1),
        newest_age_mean_s=float(np.mean(ages)) if ages else float("nan"),
        newest_age_max_s=float(np.max(ages)) if ages else float("nan"),
    )
