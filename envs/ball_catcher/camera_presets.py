"""The BallCatcher rig's camera timing presets: each camera's phase and latency.

The schedule they drive (capture ticks, jitter, drops, delivery) is the shared
:class:`observer_gym.envs.camera_rig.FrameClock`.
"""

from __future__ import annotations

import numpy as np

from observer_gym.envs.camera_rig import CameraTiming


def preset_timings(
    preset: str, cameras: int, rate_hz: float, latency_s: float, rng: np.random.Generator
) -> list[CameraTiming]:
    """Each camera's phase and latency under a timing preset (see config.CAMERA_PRESETS)."""
    period = 1.0 / rate_hz
    if preset in ("synchronised", "single"):
        return [CameraTiming(0.0, latency_s) for _ in range(cameras)]
    if preset == "alternating":
        return [CameraTiming(c * period / cameras, latency_s) for c in range(cameras)]
    if preset == "random_offsets":
        phases = rng.uniform(0.0, period, cameras)
        latencies = latency_s + rng.uniform(0.0, period, cameras)
        return [CameraTiming(float(p), float(q)) for p, q in zip(phases, latencies, strict=True)]
    raise ValueError(f"unknown camera preset {preset!r}")
