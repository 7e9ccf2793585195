"""The differential drive: what the wheels actually do with a commanded (v, omega).

The spec's robot (Tsai et al. 2009) converts the command to wheel speeds
v_l = v - omega D / 2, v_r = v + omega D / 2, scales them to its velocity and acceleration
limits, and sends them as 8-bit integers in cm/s (rounded down); the robot then moves with
v = (v_l + v_r) / 2, omega = (v_r - v_l) / D. :func:`applied_velocity` is that chain;
:func:`integrate_unicycle` moves the robot exactly for a velocity held over a step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

WHEEL_QUANTUM_MPS = 0.01  # one unit of the 8-bit wheel-speed command: 1 cm/s
WHEEL_INT_RANGE = (-128, 127)  # signed 8-bit


@dataclass(frozen=True)
class DriveLimits:
    """The wheel-level limits of the drive.

    - ``wheel_base_m``: D, the distance between the wheels.
    - ``wheel_speed_max_mps``: both wheel speeds are scaled by one factor so that neither
      exceeds this (the turning radius is kept).
    - ``wheel_accel_max_mps2``: the change of the wheel speeds over a step is scaled by one
      factor so that neither wheel accelerates faster; 0 disables the limit.
    - ``quantize``: send wheel speeds as 8-bit integers in cm/s, rounded down (floor).
    """

    wheel_base_m: float = 0.40
    wheel_speed_max_mps: float = 1.27
    wheel_accel_max_mps2: float = 0.0
    quantize: bool = False


def wheel_speeds(v_mps: float, omega_radps: float, wheel_base_m: float) -> np.ndarray:
    """(v_l, v_r) = (v - omega D / 2, v + omega D / 2)."""
    half = 0.5 * omega_radps * wheel_base_m
    return np.array([v_mps - half, v_mps + half])


def body_velocity(wheels_mps: np.ndarray, wheel_base_m: float) -> tuple[float, float]:
    """(v, omega) = ((v_l + v_r) / 2, (v_r - v_l) / D)."""
    v_l, v_r = float(wheels_mps[0]), float(wheels_mps[1])
    return 0.5 * (v_l + v_r), (v_r - v_l) / wheel_base_m


def applied_wheel_speeds(
    v_mps: float,
    omega_radps: float,
    previous_wheels_mps: np.ndarray,
    dt_s: float,
    limits: DriveLimits,
) -> np.ndarray:
    """The wheel speeds the robot runs at for a commanded (v, omega): velocity scaling,
    then acceleration scaling from the previous wheel speeds, then 8-bit quantisation."""
    # wheel_speeds and the velocity scaling in floats (the command is finite).
    half = 0.5 * omega_radps * limits.wheel_base_m
    left, right = v_mps - half, v_mps + half
    peak = max(abs(left), abs(right))
    if peak > limits.wheel_speed_max_mps:
        scale = limits.wheel_speed_max_mps / peak
        left, right = left * scale, right * scale
    wheels = np.array([left, right])
    if limits.wheel_accel_max_mps2 > 0.0:
        change = wheels - previous_wheels_mps
        largest = float(np.max(np.abs(change)))
        allowed = limits.wheel_accel_max_mps2 * dt_s
        if largest > allowed:
            wheels = previous_wheels_mps + change * (allowed / largest)
    if limits.quantize:
        counts = np.floor(wheels / WHEEL_QUANTUM_MPS + 1e-9)  # floor; 1e-9 absorbs 0.29/0.01
        wheels = np.clip(counts, *WHEEL_INT_RANGE) * WHEEL_QUANTUM_MPS
    return wheels


def integrate_unicycle(
    x_m: float, y_m: float, yaw_rad: float, v_mps: float, omega_radps: float, dt_s: float
) -> tuple[float, float, float]:
    """The pose after ``dt_s`` at (v, omega) held: an exact arc (a line when omega = 0).
    x' = v cos(psi), y' = v sin(psi), psi' = omega (the spec's z' = v cos(theta),
    x' = v sin(theta) in its axes)."""
    yaw_end = yaw_rad + omega_radps * dt_s
    if abs(omega_radps) < 1e-9:
        return (
            x_m + v_mps * dt_s * math.cos(yaw_rad),
            y_m + v_mps * dt_s * math.sin(yaw_rad),
            yaw_end,
        )
    radius = v_mps / omega_radps
    return (
        x_m + radius * (math.sin(yaw_end) - math.sin(yaw_rad)),
        y_m - radius * (math.cos(yaw_end) - math.cos(yaw_rad)),
        yaw_end,
    )
