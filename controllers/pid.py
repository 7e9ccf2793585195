"""PID per table axis: the simple baseline.

Each ball axis is a double integrator driven by one tilt axis, v' = G theta (G from
estimation/ball_table/control_model.py: tilt_y drives x, -tilt_x drives y, gain (5/7) g). Per
axis the PID asks for the acceleration

    a_des = -(kp p + ki integral(p) dt + kd v)

and commands the tilt theta = G^-1 a_des (a signed axis swap, so the axes stay
independent). The derivative term uses the observed velocity (the state or its
estimate), not a differenced position. The default gains place the double integrator's
poles at natural frequency ``omega_radps`` with damping ``damping`` (kp = omega^2,
kd = 2 zeta omega), and ki = kp omega / 10 by default. The integral
is clamped so that its term alone never asks for more than the tilt bound (anti-windup),
and it is not accumulated while the command saturates.
"""

from __future__ import annotations

import numpy as np

from observer_gym.controllers.ball_table.plant import BallTablePlant, check_plant
from observer_gym.controllers.base import StateFeedbackController, check_number

__all__ = ["PIDController"]


class PIDController(StateFeedbackController):
    """Arguments: ``plant``; ``omega_radps`` (default 2.5) and ``damping`` (default 0.9)
    set kp and kd; ``ki`` (1/s^3, default kp * omega / 10), or give ``kp``, ``ki``,
    ``kd`` directly (each None or a finite number >= 0; omega and damping finite and > 0,
    else ``ValueError``). Memory: the integral of the ball's position, per batch row."""

    name = "pid"

    def __init__(
        self,
        plant: BallTablePlant,
        omega_radps: float = 2.5,
        damping: float = 0.9,
        kp: float | None = None,
        ki: float | None = None,
        kd: float | None = None,
    ) -> None:
        check_plant("PIDController", plant)
        super().__init__(plant.obs_dim, *plant.action_bounds)
        owner = "PIDController"
        omega_radps = check_number(owner, "omega_radps", omega_radps, low=0.0, low_inclusive=False)
        damping = check_number(owner, "damping", damping, low=0.0, low_inclusive=False)
        kp, ki, kd = (
            check_number(owner, name, value, low=0.0, allow_none=True)
            for name, value in (("kp", kp), ("ki", ki), ("kd", kd))
        )
        self.omega_radps, self.damping = omega_radps, damping
        self.kp = omega_radps * omega_radps if kp is None else kp  # ** raised OverflowError
        self.kd = 2.0 * damping * omega_radps if kd is None else kd
        self.ki = self.kp * omega_radps / 10.0 if ki is None else ki
        for name, value in (("kp", self.kp), ("ki", self.ki), ("kd", self.kd)):
            if not (np.isfinite(value) and value >= 0.0):
                raise ValueError(
                    f"PIDController: {name} = {value!r}, must be finite and >= 0 (the gains "
                    f"not given follow from omega_radps = {omega_radps!r} and damping = "
                    f"{damping!r})"
                )
        self.plant = plant
        self.dt_s = plant.dt_s
        self._G_inv = np.linalg.inv(plant.model.G)
        # |G^-1 ki I| <= tilt bound: the largest integral (m s) the I term may hold.
        gain = float(np.abs(plant.model.G).max())
        self._integral_limit = np.inf if self.ki == 0.0 else plant.max_tilt_rad * gain / self.ki
        self._integral = np.zeros((0, 2))

    def reset(self) -> None:
        self._integral = np.zeros((0, 2))

    def act(self, obs: np.ndarray, episode_start: np.ndarray) -> np.ndarray:
        if self._integral.shape[0] != len(obs):
            self._integral = np.zeros((len(obs), 2))
        self._integral[episode_start] = 0.0
        pos, vel = obs[:, 0:2], obs[:, 2:4]
        integral = np.clip(
            self._integral + pos * self.dt_s, -self._integral_limit, self._integral_limit
        )
        accel = -(self.kp * pos + self.ki * integral + self.kd * vel)
        tilt = accel @ self._G_inv.T
        saturated = np.any(np.abs(tilt) > self.action_high, axis=1)
        self._integral[~saturated] = integral[~saturated]
        return tilt
