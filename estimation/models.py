"""Process models and their exact discretisation.

- :func:`discretize`: zero-order-hold input matrix and Van Loan's exact process-noise
  covariance for x' = A x + B u + G w, E[w(t) w(s)^T] = Qc delta(t - s).
- :class:`LinearModel`: a continuous-time linear model with its discretisation cached per step.
- :class:`ConstantVelocityModel`: white-acceleration model per coordinate.

Each system's own models live in its package (``estimation/<system>/models.py``).

All matrices are read-only arrays (cached per time step; copy before modifying).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

__all__ = ["ConstantVelocityModel", "LinearModel", "discretize", "readonly"]


def readonly(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


def discretize(
    A: np.ndarray, B: np.ndarray, G: np.ndarray, Qc: np.ndarray, dt_s: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact discretisation of x' = A x + B u + G w over ``dt_s`` with u held constant.

    Returns (Phi, Gamma, Qd):
    - Phi = expm(A dt);
    - Gamma = int_0^dt expm(A s) ds B, from expm([[A, B], [0, 0]] dt) = [[Phi, Gamma], [0, I]];
    - Qd = int_0^dt expm(A s) G Qc G^T expm(A s)^T ds, by Van Loan's method: with
      expm([[-A, G Qc G^T], [0, A^T]] dt) = [[., F12], [0, F22]], Phi = F22^T and
      Qd = F22^T F12 (C. F. Van Loan, IEEE TAC 23(3), 1978).

    ``Qc`` is the white noise's intensity (power spectral density): its units are those of
    w squared times seconds. ``B`` may have zero columns (no input).
    """
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    G = np.asarray(G, dtype=float)
    Qc = np.asarray(Qc, dtype=float)
    n = A.shape[0]
    if A.shape != (n, n) or B.ndim != 2 or B.shape[0] != n or G.shape[0] != n:
        raise ValueError(f"discretize: A {A.shape}, B {B.shape}, G {G.shape} do not match")
    if Qc.shape != (G.shape[1], G.shape[1]):
        raise ValueError(f"discretize: Qc has shape {Qc.shape}, expected {G.shape[1:] * 2}")
    if not dt_s > 0.0:
        raise ValueError(f"discretize: dt_s = {dt_s!r}, must be > 0")
    p = B.shape[1]
    M = np.zeros((n + p, n + p))
    M[:n, :n] = A
    M[:n, n:] = B
    E = scipy.linalg.expm(M * dt_s)
    Phi, Gamma = E[:n, :n].copy(), E[:n, n:].copy()

    V = np.zeros((2 * n, 2 * n))
    V[:n, :n] = -A
    V[:n, n:] = G @ Qc @ G.T
    V[n:, n:] = A.T
    F = scipy.linalg.expm(V * dt_s)
    Qd = F[n:, n:].T @ F[:n, n:]
    return Phi, Gamma, 0.5 * (Qd + Qd.T)


class LinearModel:
    """A continuous-time linear model x' = A x + B u + G w (w white, intensity Qc), with
    its exact zero-order-hold discretisation per step, cached per dt.

    Subclasses define :meth:`continuous`.
    """

    def continuous(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(A, B, G, Qc)."""
        raise NotImplementedError

    def matrices(self, dt_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(Phi, Gamma, Q) for the step ``dt_s`` with u held, exact, cached (read-only)."""
        cache = self.__dict__.setdefault("_cache", {})  # made on first use: no super().__init__
        key = float(dt_s)
        cached = cache.get(key)
        if cached is None:
            Phi, Gamma, Q = discretize(*self.continuous(), key)
            cached = cache[key] = (readonly(Phi), readonly(Gamma), readonly(Q))
        return cached


class ConstantVelocityModel(LinearModel):
    """White-acceleration (constant-velocity) model for ``dim`` coordinates.

    State (q_1..q_dim, q'_1..q'_dim); q'' = a + w with a an optional input and w white with
    intensity accel_std^2 x 1 s, i.e. (units of q / s^2)^2 s; its 1-s average has std
    ``accel_std``. Per coordinate, Qd = q [[dt^3/3, dt^2/2], [dt^2/2, dt]].
    """

    def __init__(self, dim: int, accel_std: float) -> None:
        if dim < 1:
            raise ValueError(f"ConstantVelocityModel: dim = {dim!r}, must be >= 1")
        if not (np.isfinite(accel_std) and accel_std >= 0.0):
            raise ValueError(f"ConstantVelocityModel: accel_std = {accel_std!r}, must be >= 0")
        self.dim = int(dim)
        self.accel_std = float(accel_std)
        self.n = 2 * self.dim
        C = np.zeros((self.dim, self.n))
        C[:, : self.dim] = np.eye(self.dim)
        self.C = readonly(C)

    def continuous(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(A, B, G, Qc) of x' = A x + B a + G w."""
        d, eye = self.dim, np.eye(self.dim)
        A = np.zeros((2 * d, 2 * d))
        A[:d, d:] = eye
        B = np.zeros((2 * d, d))
        B[d:, :] = eye
        return A, B, B.copy(), self.accel_std**2 * eye
