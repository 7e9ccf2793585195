"""BallCatcher's process models: the ball in free flight (docs/spec/catcher.md (19)-(20)),
linear (:class:`BallisticModel`, the viewline filter's) and nonlinear with optional air drag
(:class:`BallFlight`, the pixel EKF's and the visible-oracle's)."""

from __future__ import annotations

from typing import Literal, overload

import numpy as np

from observer_gym.envs.ball_catcher.geometry import BALL_RADIUS_M
from observer_gym.envs.ball_catcher.scene import AIR_DENSITY_KGPM3, DRAG_COEFFICIENT
from observer_gym.envs.sim import GRAVITY_MPS2
from observer_gym.estimation.models import LinearModel, readonly

__all__ = ["BALL_MASS_KG", "BallFlight", "BallisticModel", "env_drag_per_m"]

BALL_MASS_KG = 0.05  # envs/assets/ball.urdf


class BallisticModel(LinearModel):
    """A ball in free flight without air drag (docs/spec/catcher.md (19)-(20)), world frame z up.

    State x = (x, y, z, vx, vy, vz) in m and m/s; input u = 1 (gravity, held): the paper's
    frame has y up, ours has z up, so B = (0, 0, 0, 0, 0, -g) with g = GRAVITY_MPS2 and the
    paper's Gamma = (0, -g h^2/2, 0, 0, -g h, 0)^T becomes (0, 0, -g h^2/2, 0, 0, -g h)^T.
    Continuous model p' = v, v' = (0, 0, -g) u + w, with w white acceleration noise of
    intensity ``accel_noise_std``^2 x 1 s per axis, in (m/s^2)^2 s = m^2/s^3 (its 1-s
    average has std ``accel_noise_std`` m/s^2); it stands for drag, spin and model error.

    Exact discretisation over h (what :func:`discretize` gives, checked in the tests):
    Phi = [[I, h I], [0, I]] (19), Gamma = (0, 0, -g h^2/2, 0, 0, -g h)^T (20), and per
    axis R1 = q [[h^3/3, h^2/2], [h^2/2, h]]. :meth:`matrices` writes these closed forms
    instead of calling ``expm`` and does not cache: capture times are aperiodic, so every
    interval differs and a per-dt cache would only grow. Negative h is allowed for Phi and
    Gamma (the deterministic flight backwards), not for R1.
    """

    n = 6

    def __init__(self, accel_noise_std: float = 0.5, gravity_mps2: float = GRAVITY_MPS2) -> None:
        if not (np.isfinite(accel_noise_std) and accel_noise_std >= 0.0):
            raise ValueError(f"BallisticModel: accel_noise_std = {accel_noise_std!r}, must be >= 0")
        self.accel_noise_std = float(accel_noise_std)
        self.gravity_mps2 = float(gravity_mps2)
        self.u = readonly(np.ones(1))  # (20): u(kh) = 1

    def continuous(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(A, B, G, Qc) of x' = A x + B u + G w, u = 1."""
        A = np.zeros((6, 6))
        A[:3, 3:] = np.eye(3)  # p' = v
        B = np.zeros((6, 1))
        B[5, 0] = -self.gravity_mps2  # v_z' = -g (z up)
        G = np.zeros((6, 3))
        G[3:, :] = np.eye(3)  # v' = ... + w
        return A, B, G, self.accel_noise_std**2 * np.eye(3)

    def transition(self, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
        """(Phi (6, 6), Gamma (6, 1)) over ``dt_s`` (any sign), (19)-(20)."""
        h = float(dt_s)
        Phi = np.eye(6)
        Phi[:3, 3:] = h * np.eye(3)  # (19)
        Gamma = np.zeros((6, 1))
        Gamma[2, 0] = -0.5 * self.gravity_mps2 * h * h  # (20), z up
        Gamma[5, 0] = -self.gravity_mps2 * h
        return Phi, Gamma

    def matrices(self, dt_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(Phi, Gamma, R1) for ``dt_s`` > 0, exact, in closed form (read-only, fresh)."""
        h = float(dt_s)
        if not h > 0.0:
            raise ValueError(f"BallisticModel.matrices: dt_s = {dt_s!r}, must be > 0")
        Phi, Gamma = self.transition(h)
        q = self.accel_noise_std**2
        eye = np.eye(3)
        Q = np.zeros((6, 6))
        Q[:3, :3] = q * h**3 / 3.0 * eye
        Q[:3, 3:] = Q[3:, :3] = q * h**2 / 2.0 * eye
        Q[3:, 3:] = q * h * eye
        return readonly(Phi), readonly(Gamma), readonly(Q)


class BallFlight:
    """The ball's flight as a nonlinear model, for the EKF and the oracle's prediction:
    gravity and, optionally, quadratic air drag, world frame z up.

        p' = v,   v' = (0, 0, -g) - k |v| v + w,   k = ``drag_per_m`` (1/m)

    with w white acceleration noise as in :class:`BallisticModel` (intensity
    ``accel_noise_std``^2 per axis). The env's drag (``air_drag=True``) is
    F = -1/2 rho C_d A |v| v on a ball of mass m, so k = rho C_d A / (2 m)
    (:func:`env_drag_per_m`).

    :meth:`propagate` over ``dt_s``: without drag (k = 0) exactly BallisticModel's
    Phi x + Gamma, F = Phi and its R1 (so the EKF's prediction is the linear filter's);
    with drag the classical Runge-Kutta (RK4) in substeps of at most ``max_substep_s``,
    F = I + A h + A^2 h^2 / 2 per substep with A = df/dx at the substep's start (second
    order in h, enough for a covariance over a few ms), and R1 still BallisticModel's.
    """

    def __init__(
        self,
        drag_per_m: float = 0.0,
        accel_noise_std: float = 0.5,
        gravity_mps2: float = GRAVITY_MPS2,
        max_substep_s: float = 0.005,
    ) -> None:
        if not (np.isfinite(drag_per_m) and drag_per_m >= 0.0):
            raise ValueError(f"BallFlight: drag_per_m = {drag_per_m!r}, must be >= 0")
        if not max_substep_s > 0.0:
            raise ValueError(f"BallFlight: max_substep_s = {max_substep_s!r}, must be > 0")
        self.drag_per_m = float(drag_per_m)
        self.linear = BallisticModel(accel_noise_std, gravity_mps2)
        self.gravity_mps2 = float(gravity_mps2)
        self.max_substep_s = float(max_substep_s)

    def derivative(self, x: np.ndarray) -> np.ndarray:
        """x' = (v, (0, 0, -g) - k |v| v)."""
        v = x[3:]
        # v' = -g e_z - k |v| v
        accel = -self.drag_per_m * float(np.sqrt(v @ v)) * v
        accel[2] -= self.gravity_mps2
        return np.concatenate([v, accel])

    def _jacobian(self, x: np.ndarray) -> np.ndarray:
        """A = df/dx: [[0, I], [0, -k (|v| I + v v^T / |v|)]]."""
        A = np.zeros((6, 6))
        A[:3, 3:] = np.eye(3)
        v = x[3:]
        speed = float(np.sqrt(v @ v))
        if speed > 0.0:
            # d(-k |v| v)/dv = -k (|v| I + v v^T / |v|)
            A[3:, 3:] = -self.drag_per_m * (speed * np.eye(3) + np.outer(v, v) / speed)
        return A

    def state_at(self, x: np.ndarray, dt_s: float) -> np.ndarray:
        """The state ``dt_s`` (>= 0) later, without noise."""
        return self.propagate(x, dt_s, with_jacobian=False)[0]

    @overload
    def propagate(
        self, x: np.ndarray, dt_s: float, with_jacobian: Literal[True] = True
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...
    @overload
    def propagate(
        self, x: np.ndarray, dt_s: float, with_jacobian: bool
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]: ...
    def propagate(
        self, x: np.ndarray, dt_s: float, with_jacobian: bool = True
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """(f(x), F = df/dx, R1) over ``dt_s`` >= 0; with drag, F and R1 are None unless
        ``with_jacobian``. Over dt_s = 0: (x, I, 0)."""
        x = np.asarray(x, dtype=float)
        h = float(dt_s)
        if not h >= 0.0:
            raise ValueError(f"BallFlight.propagate: dt_s = {dt_s!r}, must be >= 0")
        if h == 0.0:
            return x.copy(), np.eye(6), np.zeros((6, 6))
        if self.drag_per_m == 0.0:
            Phi, Gamma, Q = self.linear.matrices(h)
            # x(t + h) = Phi x + Gamma u, u = 1 (19)-(20)
            return Phi @ x + Gamma[:, 0], Phi, Q
        n = int(np.ceil(h / self.max_substep_s - 1e-9))
        step = h / n
        F = np.eye(6) if with_jacobian else None
        for _ in range(n):
            if with_jacobian:
                A = self._jacobian(x)
                # F <- (I + A h + A^2 h^2 / 2) F
                F = (np.eye(6) + step * A + 0.5 * step * step * (A @ A)) @ F
            # RK4: x <- x + h/6 (k1 + 2 k2 + 2 k3 + k4)
            k1 = self.derivative(x)
            k2 = self.derivative(x + 0.5 * step * k1)
            k3 = self.derivative(x + 0.5 * step * k2)
            k4 = self.derivative(x + step * k3)
            x = x + step / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        R1 = self.linear.matrices(h)[2] if with_jacobian else None
        return x, F, R1


def env_drag_per_m(air_drag: bool) -> float:
    """k (1/m) of :class:`BallFlight` for the BallCatcher env's air drag: rho C_d A / (2 m)
    with the env's air density, drag coefficient, the ball's radius and its mass (the
    0.05 kg of envs/assets/ball.urdf); 0 without drag."""
    if not air_drag:
        return 0.0
    area_m2 = np.pi * BALL_RADIUS_M**2
    return AIR_DENSITY_KGPM3 * DRAG_COEFFICIENT * area_m2 / (2.0 * BALL_MASS_KG)
