"""Throws: where the ball is launched from and how, and where it crosses a plane.

A throw is drawn so that, without drag, the ball's centre crosses the box's front plane
(x = the hole's home x) after a flight time T uniform in [flight_time_min_s,
flight_time_max_s], at a point uniform in the disc of radius ``target_radius_m`` around
the hole's home (in the plane), from a launch point uniform in the cube of half-side
``launch_spread_m`` around (``launch_x_m``, 0, ``launch_height_m``). The launch velocity
follows in closed form: with p(t) = p0 + v0 t - (0, 0, g t^2 / 2),
v0 = (c - p0) / T + (0, 0, g T / 2).

MAX_THROW_SPEED_MPS bounds every throw: the fastest the configuration's ranges allow
(:func:`fastest_throw_mps` at their extremes, 91.7 m/s: launched 9 m out and 4 m high,
arriving after 0.1 s) and reset's ``throw`` option. The physics keeps the
ball out of the box's walls up to it (scene.py; tests/envs/test_ball_catcher_tunnelling.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from observer_gym.envs.ball_catcher import geometry as geo
from observer_gym.envs.sim import GRAVITY_MPS2

MAX_THROW_SPEED_MPS = 100.0


@dataclass(frozen=True)
class Throw:
    """A throw: launch position and velocity (world), and the drag-free crossing of the
    box's home plane (time after launch, point; both None for a throw that never reaches
    the plane)."""

    launch_pos_world: np.ndarray
    launch_vel_world: np.ndarray
    crossing_time_s: float | None
    crossing_pos_world: np.ndarray | None


def throw_through(launch_pos_world, crossing_pos_world, flight_time_s: float) -> Throw:
    """The drag-free throw from ``launch_pos_world`` that reaches ``crossing_pos_world``
    after ``flight_time_s``."""
    p0 = np.asarray(launch_pos_world, dtype=float)
    c = np.asarray(crossing_pos_world, dtype=float)
    t = float(flight_time_s)
    if not t > 0.0:
        raise ValueError(f"flight_time_s = {flight_time_s!r}, must be > 0")
    v0 = (c - p0) / t
    v0[2] += 0.5 * GRAVITY_MPS2 * t
    return Throw(p0, v0, t, c)


def sample_throw(config, rng: np.random.Generator) -> Throw:
    """A throw drawn from the distribution of ``config`` (a BallCatcherConfig)."""
    spread = config.launch_spread_m
    launch = np.array([config.launch_x_m, 0.0, config.launch_height_m]) + rng.uniform(
        -spread, spread, 3
    )
    radius = config.target_radius_m * np.sqrt(rng.uniform())
    angle = rng.uniform(0.0, 2.0 * np.pi)
    crossing = geo.HOLE_HOME_WORLD + radius * np.array([0.0, np.cos(angle), np.sin(angle)])
    flight_time = rng.uniform(config.flight_time_min_s, config.flight_time_max_s)
    return throw_through(launch, crossing, flight_time)


def plane_crossing(
    ball_pos_world, ball_vel_world, plane_x_m: float, gravity_mps2: float = GRAVITY_MPS2
) -> tuple[float, np.ndarray] | None:
    """When (s from now) and where a drag-free ball crosses the plane x = ``plane_x_m``
    moving toward -x; None if it moves away from the plane or along it."""
    p = np.asarray(ball_pos_world, dtype=float)
    v = np.asarray(ball_vel_world, dtype=float)
    if not v[0] < 0.0:
        return None
    t = (plane_x_m - p[0]) / v[0]
    if t < 0.0:
        return None
    point = p + v * t
    point[2] -= 0.5 * gravity_mps2 * t * t
    return float(t), point


def fastest_throw_mps(config) -> float:
    """The fastest launch speed ``sample_throw`` can draw from ``config`` (a
    BallCatcherConfig): the launch cube's corners, crossings on the target circle (every
    degree) and the shortest and longest flight times (the speed is convex in the launch
    and crossing points)."""
    spread = config.launch_spread_m
    corners = np.array(np.meshgrid(*[[-spread, spread]] * 3)).T.reshape(-1, 3)
    launches = np.array([config.launch_x_m, 0.0, config.launch_height_m]) + corners
    angles = np.radians(np.arange(360))
    circle = np.stack([np.zeros_like(angles), np.cos(angles), np.sin(angles)], axis=1)
    crossings = geo.HOLE_HOME_WORLD + config.target_radius_m * circle
    fastest = 0.0
    for t in (config.flight_time_min_s, config.flight_time_max_s):
        v = (crossings[None, :, :] - launches[:, None, :]) / t
        v[..., 2] += 0.5 * GRAVITY_MPS2 * t
        fastest = max(fastest, float(np.linalg.norm(v, axis=-1).max()))
    return fastest
