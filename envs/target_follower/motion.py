"""How the target and the occluder move.

Target motions (``TargetFollowerConfig.target_motion``):
- ``"profile"``: spec (44), in world axes (x forward at the start, y left, z up):
  V_t = v_t (cos theta_t, sin theta_t, 0) with v_t = 0.15 cos(pi t / 20) m/s and
  theta_t = theta_t(0) + (5 pi / 72) t, the continuous form of (44) (its samples at
  t = nT are the spec's; the spec's (v_x, v_z) are our (v_y, v_x)). The turn rate is
  ``profile_turn_rate_radps`` (5 pi / 72 by default; 0 makes the target go back and forth
  on a line, which isolates what the turning costs an estimator).
- ``"random_walk"``: a smooth random walk: an Ornstein-Uhlenbeck process (correlation
  time 2 s, stationary std ``walk_speed_mps`` per horizontal axis) drives the velocity
  through a first-order lag of 0.5 s, so the velocity is smooth (a walker's acceleration
  is bounded) with a stationary std of 0.89 ``walk_speed_mps``; the height follows a
  slower, spring-held one (std 5 cm/s) around its start.
- ``"static"``: the target stands still.
Pushes (``push_rate_hz``) add a horizontal velocity kick of up to ``push_speed_mps``
that decays with a 1 s time constant, on top of any motion.

The occluder (a person-sized box) walks in from the side to the point halfway between
the camera and the target, stays on that line (following it) for ``hold_s`` and walks on
out of the way: enter and exit take ``OCCLUDER_WALK_S`` each.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

PROFILE_SPEED_MPS = 0.15  # (44): v_t = 15 cm/s cos(n pi T / 20)
PROFILE_TURN_RATE_RADPS = 5.0 * math.pi / 72.0  # (44): theta_t += T 5 pi / 72
WALK_TIME_CONSTANT_S = 2.0
WALK_LAG_S = 0.5  # the velocity follows the Ornstein-Uhlenbeck drive through this lag
HEIGHT_SPEED_STD_MPS = 0.05
HEIGHT_SPRING_PER_S = 0.5
PUSH_DECAY_S = 1.0

OCCLUDER_WALK_S = 1.0  # time to walk in (and out)
OCCLUDER_SIDE_OFFSET_M = 1.5  # where it starts and ends, beside the line of sight
OCCLUDER_LINE_FRACTION = 0.5  # its place on the camera-target line while hiding
OCCLUDER_HALF_EXTENTS_M = np.array([0.125, 0.225, 0.95])  # along the line, across, up
OCCLUDER_PARKED_WORLD = np.array([0.0, 0.0, -20.0])


class TargetMotion:
    """The target's position and velocity over time; all randomness from ``rng``."""

    def __init__(
        self,
        kind: str,
        pos_world: np.ndarray,
        rng: np.random.Generator,
        walk_speed_mps: float = 0.1,
        push_rate_hz: float = 0.0,
        push_speed_mps: float = 0.2,
        heading_rad: float = 0.0,
        turn_rate_radps: float = PROFILE_TURN_RATE_RADPS,
    ) -> None:
        self.kind = kind
        self.pos = np.array(pos_world, dtype=float)
        self._rng = rng
        self._home_height_m = float(self.pos[2])
        self._walk_speed = walk_speed_mps
        self._push_rate = push_rate_hz
        self._push_speed = push_speed_mps
        self._heading0 = heading_rad
        self._turn_rate = turn_rate_radps
        self._walk_vel = np.zeros(3)
        self._walk_drive = np.zeros(3)
        if kind == "random_walk":
            self._walk_drive[:2] = rng.normal(0.0, walk_speed_mps, 2)
            self._walk_vel[:2] = self._walk_drive[:2]
        self._kick = np.zeros(3)
        self.time_s = 0.0

    def base_velocity(self, t_s: float) -> np.ndarray:
        if self.kind == "profile":
            speed = PROFILE_SPEED_MPS * math.cos(math.pi * t_s / 20.0)  # (44)
            heading = self._heading0 + self._turn_rate * t_s  # (44)
            return np.array([speed * math.cos(heading), speed * math.sin(heading), 0.0])
        if self.kind == "random_walk":
            return self._walk_vel.copy()
        return np.zeros(3)

    @property
    def velocity(self) -> np.ndarray:
        """The target's world velocity now (m/s)."""
        if self.kind == "random_walk":  # base_velocity's copy, without making it
            return self._walk_vel + self._kick
        return self.base_velocity(self.time_s) + self._kick

    def advance(
        self, dt_s: float, substeps: int, after_substep: Callable[[int], None] | None = None
    ) -> None:
        """Move the target over ``dt_s`` in ``substeps`` integration steps, calling
        ``after_substep(k)`` after step k (0-based). A push drawn for this interval starts
        at its end."""
        rng = self._rng
        push = rng.uniform() < 1.0 - math.exp(-self._push_rate * dt_s)
        push_speed = rng.uniform(0.0, self._push_speed)
        push_dir = rng.uniform(0.0, 2.0 * math.pi)
        h = dt_s / substeps
        noise = rng.normal(size=(substeps, 3))
        decay = math.exp(-h / PUSH_DECAY_S)
        for k in range(substeps):
            t = self.time_s
            if self.kind == "profile":  # midpoint rule on the smooth profile
                self.pos += h * (self.base_velocity(t + 0.5 * h) + self._kick)
            else:
                self.pos += h * (self._walk_vel + self._kick)
                if self.kind == "random_walk":
                    self._step_walk(h, noise[k])
            self._kick *= decay
            self.time_s = t + h
            if after_substep is not None:
                after_substep(k)
        if push:
            self._kick[:2] += push_speed * np.array([math.cos(push_dir), math.sin(push_dir)])

    def _step_walk(self, h: float, noise: np.ndarray) -> None:
        """Euler-Maruyama step of the Ornstein-Uhlenbeck drive; the velocity lags it."""
        tau = WALK_TIME_CONSTANT_S
        gain = math.sqrt(2.0 * h / tau)
        w = self._walk_drive
        w[:2] += -w[:2] * h / tau + self._walk_speed * gain * noise[:2]
        spring = -HEIGHT_SPRING_PER_S * (self.pos[2] - self._home_height_m)
        w[2] += (spring - w[2]) * h / tau + HEIGHT_SPEED_STD_MPS * gain * noise[2]
        self._walk_vel += (w - self._walk_vel) * (h / WALK_LAG_S)


def _smoothstep(s: float) -> float:
    s = min(max(s, 0.0), 1.0)
    return s * s * (3.0 - 2.0 * s)


class OccluderWalk:
    """Occlusion events: each starts at a time, walks in, hides the target, walks out."""

    def __init__(self, hold_s: float, rate_hz: float, starts_s=()) -> None:
        self.hold_s = float(hold_s)
        self.rate_hz = float(rate_hz)
        self.pending = sorted(float(t) for t in starts_s)
        self.active_start_s: float | None = None
        self.side = 1.0

    @property
    def duration_s(self) -> float:
        return 2.0 * OCCLUDER_WALK_S + self.hold_s

    def update(self, t_s: float, dt_s: float, rng: np.random.Generator) -> None:
        """Start or end an event at time ``t_s`` (two uniform draws per call: ``random()``
        is ``uniform()``'s number, cheaper)."""
        draw, side_draw = rng.random(), rng.random()
        if self.active_start_s is not None and t_s >= self.active_start_s + self.duration_s:
            self.active_start_s = None
        if self.active_start_s is not None:
            return
        if self.pending and t_s >= self.pending[0] - 1e-9:
            self.active_start_s = self.pending.pop(0)
        elif draw < 1.0 - math.exp(-self.rate_hz * dt_s):
            self.active_start_s = t_s
        else:
            return
        self.side = 1.0 if side_draw < 0.5 else -1.0

    def hiding(self, t_s: float) -> bool:
        """Whether the occluder stands on the line of sight (its hold phase)."""
        if self.active_start_s is None:
            return False
        s = t_s - self.active_start_s
        return OCCLUDER_WALK_S <= s <= OCCLUDER_WALK_S + self.hold_s

    def pose(self, t_s: float, eye_world: np.ndarray, target_world: np.ndarray):
        """(centre_world, yaw_rad) of the occluder at ``t_s``, or None when not walking."""
        if self.active_start_s is None:
            return None
        s = t_s - self.active_start_s
        if s > self.duration_s:
            return None
        if s < OCCLUDER_WALK_S:
            offset = self.side * (1.0 - _smoothstep(s / OCCLUDER_WALK_S))
        elif s <= OCCLUDER_WALK_S + self.hold_s:
            offset = 0.0
        else:
            offset = -self.side * _smoothstep((s - OCCLUDER_WALK_S - self.hold_s) / OCCLUDER_WALK_S)
        line = np.asarray(target_world[:2], dtype=float) - np.asarray(eye_world[:2], dtype=float)
        length = float(np.hypot(*line))
        direction = line / length if length > 1e-9 else np.array([1.0, 0.0])
        across = np.array([-direction[1], direction[0]])
        xy = (
            eye_world[:2] + OCCLUDER_LINE_FRACTION * line + OCCLUDER_SIDE_OFFSET_M * offset * across
        )
        centre = np.array([xy[0], xy[1], OCCLUDER_HALF_EXTENTS_M[2]])
        return centre, math.atan2(direction[1], direction[0])
