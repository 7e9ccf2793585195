"""The camera rig's timing: when each camera captures, which frames are lost, when each
frame is delivered.

Times are whole physics steps (ticks) of the world, so a frame is rendered (or projected)
from exactly the world state at its capture time and every time is exact (tick x dt).
Camera c captures its k-th frame at phase_c + k / rate (+ Gaussian jitter, clipped to
a quarter period, rounded to a tick and kept after the previous capture); each frame is
lost with probability ``frame_drop_prob``; a kept frame is delivered ``latency_c``
after its capture, at the end of the first env step at or after that time.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class CameraTiming:
    phase_s: float
    latency_s: float


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


@dataclass
class _CameraClock:
    timing: CameraTiming
    index: int = 0  # the next frame's number
    next_tick: int = 0
    last_tick: int = -1


@dataclass(order=True)
class PendingFrame:
    """A captured frame waiting for its delivery tick."""

    delivery_tick: int
    capture_tick: int
    camera_id: int
    payload: dict = field(compare=False)


class FrameClock:
    """Capture and delivery schedule of every camera for one episode.

    Args:
        timings: each camera's phase and latency.
        rate_hz: frame rate (every camera).
        physics_dt_s: the tick.
        jitter_s: std of the capture-time jitter.
        drop_prob: probability a frame is lost.
        rng: the env's generator (drawn in a fixed order, so episodes are reproducible).
    """

    def __init__(
        self,
        timings: list[CameraTiming],
        rate_hz: float,
        physics_dt_s: float,
        jitter_s: float,
        drop_prob: float,
        rng: np.random.Generator,
    ) -> None:
        self.rate_hz = float(rate_hz)
        self.dt_s = float(physics_dt_s)
        self.jitter_s = float(jitter_s)
        self.drop_prob = float(drop_prob)
        self.rng = rng
        self.clocks = [_CameraClock(t) for t in timings]
        for clock in self.clocks:
            clock.next_tick = self._draw_tick(clock)
        self.pending: list[PendingFrame] = []

    def _draw_tick(self, clock: _CameraClock) -> int:
        t = clock.timing.phase_s + clock.index / self.rate_hz
        if self.jitter_s > 0.0:
            limit = 0.25 / self.rate_hz
            t += float(np.clip(self.rng.normal(0.0, self.jitter_s), -limit, limit))
        return max(round(t / self.dt_s), clock.last_tick + 1, 0)

    def captures_at(self, tick: int) -> list[int]:
        """The cameras that capture at ``tick`` (advancing their schedules); dropped frames
        are not listed."""
        cameras = []
        for camera_id, clock in enumerate(self.clocks):
            if clock.next_tick != tick:
                continue
            clock.last_tick = tick
            clock.index += 1
            clock.next_tick = self._draw_tick(clock)
            if self.drop_prob > 0.0 and self.rng.uniform() < self.drop_prob:
                continue
            cameras.append(camera_id)
        return cameras

    def add(self, camera_id: int, capture_tick: int, payload: dict) -> None:
        latency_ticks = round(self.clocks[camera_id].timing.latency_s / self.dt_s)
        self.pending.append(
            PendingFrame(capture_tick + latency_ticks, capture_tick, camera_id, payload)
        )

    def deliver(self, tick: int) -> list[dict]:
        """The payloads of the frames due by ``tick``, in capture-time order."""
        due = sorted(f for f in self.pending if f.delivery_tick <= tick)
        self.pending = [f for f in self.pending if f.delivery_tick > tick]
        return [f.payload for f in sorted(due, key=lambda f: (f.capture_tick, f.camera_id))]
