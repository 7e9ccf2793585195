"""BallCatcher's process model: the ball in free flight (docs/spec/catcher.md (19)-(20))."""

from __future__ import annotations

import numpy as np

from observer_gym.envs.sim import GRAVITY_MPS2
from observer_gym.estimation.models import LinearModel, readonly

__all__ = ["BallisticModel"]


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
