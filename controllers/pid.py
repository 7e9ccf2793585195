"""PID per axis on any system's double-integrator axes: the simple baseline.

The plant (:class:`~observer_gym.controllers.plant.AxesPlant`) names k axes, each a double
integrator p' = v, v' = a driven through a = G u (G = ``accel_per_input`` (k, k) of its
:class:`~observer_gym.controllers.plant.DoubleIntegratorAxes`; BallTable: tilt_y drives x,
-tilt_x drives y, gain (5/7) g, from its control model). Per axis the PID asks for the
acceleration

    a_des = -(kp p + ki integral(p) dt + kd v)

and commands u = G^-1 a_des (BallTable: a signed axis swap, so the axes stay
independent). The derivative term uses the observed velocity (the state or its
estimate), not a differenced position. The default gains place the double integrator's
poles at natural frequency ``omega_radps`` with damping ``damping`` (kp = omega^2,
kd = 2 zeta omega), and ki = kp omega / 10 by default. The integral is clamped at
u_max max|G| / ki per axis (u_max the smallest upper action bound), so that for a G whose
entries have one magnitude (BallTable's) its term alone never asks for more than the
action bound (anti-windup); it is not accumulated while the command saturates.
"""

from __future__ import annotations

import numpy as np

from observer_gym.controllers.base import StateFeedbackController, check_number
from observer_gym.controllers.plant import AxesPlant, check_plant

__all__ = ["PIDController"]


class PIDController(StateFeedbackController):
    """Arguments: ``plant`` (an :class:`~observer_gym.controllers.plant.AxesPlant`, e.g.
    ``BallTablePlant``); ``omega_radps`` (default 2.5) and ``damping`` (default 0.9) set kp
    and kd; ``ki`` (1/s^3, default kp * omega / 10), or give ``kp``, ``ki``, ``kd``
    directly (each None or a finite number >= 0; omega and damping finite and > 0, else
    ``ValueError``). Memory: the integral of the axes' positions, per batch row."""

    name = "pid"

    def __init__(
        self,
        plant: AxesPlant,
        omega_radps: float = 2.5,
        damping: float = 0.9,
        kp: float | None = None,
        ki: float | None = None,
        kd: float | None = None,
    ) -> None:
        check_plant("PIDController", plant, AxesPlant)
        super().__init__(plant.obs_dim, *plant.action_bounds)
        owner = "PIDController"
        omega_radps = check_number(owner, "omega_radps", omega_radps, low=0.0, low_inclusive=False)
        damping = check_number(owner, "damping", damping, low=0.0, low_inclusive=False)
        kp, ki, kd = (
            check_number(owner, name, value, low=0.0, allow_none=True)
            for name, value in (("kp", kp), ("ki", ki), ("kd", kd))
        )
        self.omega_radps, self.damping = omega_radps, damping
        # kp = omega^2, kd = 2 zeta omega, ki = kp omega / 10
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
        axes = plant.axes()
        G = np.asarray(axes.accel_per_input, dtype=float)
        k = len(self.action_high)
        if G.shape != (k, k) or not np.all(np.isfinite(G)) or np.linalg.matrix_rank(G) < k:
            raise ValueError(
                f"PIDController: the plant's accel_per_input must be an invertible ({k}, {k}) "
                f"matrix (one axis per input), got {G.tolist()}"
            )
        self._positions, self._velocities = axes.positions, axes.velocities
        self._G_inv = np.linalg.inv(G)
        # |G^-1 ki I| <= u_max: the largest integral (axis units x s) the I term may hold.
        gain = float(np.abs(G).max())
        u_max = float(np.min(self.action_high))
        self._integral_limit = np.inf if self.ki == 0.0 else u_max * gain / self.ki
        self._integral = np.zeros((0, k))

    def reset(self) -> None:
        self._integral = np.zeros((0, len(self.action_high)))

    def act(self, obs: np.ndarray, episode_start: np.ndarray) -> np.ndarray:
        if self._integral.shape[0] != len(obs):
            self._integral = np.zeros((len(obs), len(self.action_high)))
        self._integral[episode_start] = 0.0
        pos, vel = obs[:, self._positions], obs[:, self._velocities]
        integral = np.clip(
            self._integral + pos * self.dt_s, -self._integral_limit, self._integral_limit
        )
        # a_des = -(kp p + ki integral(p) dt + kd v)
        accel = -(self.kp * pos + self.ki * integral + self.kd * vel)
        # u = G^-1 a_des
        command = accel @ self._G_inv.T
        saturated = np.any(np.abs(command) > self.action_high, axis=1)
        self._integral[~saturated] = integral[~saturated]
        return command
