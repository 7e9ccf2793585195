"""Process models and their exact discretisation.

- :func:`discretize`: zero-order-hold input matrix and Van Loan's exact process-noise
  covariance for x' = A x + B u + G w, E[w(t) w(s)^T] = Qc delta(t - s).
- :class:`RollingBallModel`: spec/table_ball.md "Dynamics and estimator", both axes.
- :class:`ConstantVelocityModel`: white-acceleration model per coordinate.

All matrices are read-only arrays (cached per time step; copy before modifying).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from observer_gym.envs.ball_table.geometry import BALL_TRAVEL_M
from observer_gym.envs.sim import GRAVITY_MPS2

__all__ = [
    "ROLLING_ACCEL_FACTOR",
    "BallisticModel",
    "ConstantVelocityModel",
    "RollingBallModel",
    "RollingBallParams",
    "discretize",
]

# A solid sphere rolling without slipping: a = (5/7) g sin(theta) (spec/table_ball.md).
ROLLING_ACCEL_FACTOR = 5.0 / 7.0


def _readonly(a: np.ndarray) -> np.ndarray:
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
            cached = cache[key] = (_readonly(Phi), _readonly(Gamma), _readonly(Q))
        return cached


@dataclass(frozen=True)
class RollingBallParams:
    """Noise parameters of :class:`RollingBallModel` (spec/table_ball.md).

    - ``sigma_w`` (m/s^2): std of the Gauss-Markov disturbance w2 (its stationary std),
      and the scale of the white disturbance w1: w1 has the intensity (PSD)
      sigma_w^2 x 1 s, in (m/s^2)^2 s = m^2/s^3, i.e. its 1-s average has std sigma_w.
      The spec's best ratio: sigma_w = 1, sigma_v = 0.005 m.
    - ``beta`` (1/s): inverse correlation time of w2, w2' = -beta w2 + sqrt(2 beta)
      sigma_w eps with eps unit-intensity white noise, so w2's driving noise has intensity
      2 beta sigma_w^2, in (m/s^3)^2 s = m^2/s^5. The report does not give beta. We take
      5 /s (0.2 s correlation time): the disturbances it stands for are forces from the
      table's motion, which follow the arm's tilt transients, and the arm settles a tilt
      step in about 0.2 s (tests/envs/test_ball_table_physics.py, STEP_SETTLING_S).
    - ``sigma_v_m`` (m): std of the position measurement noise.
    - ``w1_psd_time_s`` (s): the 1 s in w1's intensity sigma_w^2 x 1 s, exposed so that w1
      can be tuned apart from w2.
    """

    sigma_w: float = 1.0
    beta: float = 5.0
    sigma_v_m: float = 0.005
    w1_psd_time_s: float = 1.0

    def __post_init__(self) -> None:
        for name in ("sigma_w", "beta", "sigma_v_m", "w1_psd_time_s"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0.0):
                raise ValueError(f"RollingBallParams.{name} = {value!r}, must be finite and > 0")


class RollingBallModel(LinearModel):
    """The BallTable estimator model, both table axes (spec/table_ball.md).

    State x = (p_x, p_y, v_x, v_y, w_x, w_y): ball position (m) and velocity (m/s) in the
    table frame and the Gauss-Markov disturbance w2 (m/s^2) per axis. Input u = a (2,), the
    in-plane gravity acceleration (m/s^2) from :meth:`gravity_acceleration`. Per axis:

        p' = v,   v' = a + w1 + w2,   w2' = -beta w2 + sqrt(2 beta) sigma_w eps

    (the report's text writes -beta w1 by mistake). Measurement: y = (p_x, p_y) + e,
    e ~ N(0, sigma_v^2 I). Discretised exactly (zero-order hold on a) by :func:`discretize`.
    """

    n = 6
    m = 2

    def __init__(self, params: RollingBallParams | None = None) -> None:
        self.params = RollingBallParams() if params is None else params
        C = np.zeros((2, 6))
        C[0, 0] = C[1, 1] = 1.0
        self.C = _readonly(C)
        self.R = _readonly(self.params.sigma_v_m**2 * np.eye(2))

    def continuous(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(A, B, G, Qc) of x' = A x + B a + G w, w = (w1_x, w1_y, eps_x, eps_y)."""
        beta, sigma_w = self.params.beta, self.params.sigma_w
        I2 = np.eye(2)
        A = np.zeros((6, 6))
        A[0:2, 2:4] = I2  # p' = v
        A[2:4, 4:6] = I2  # v' = ... + w2
        A[4:6, 4:6] = -beta * I2  # w2' = -beta w2 + ...
        B = np.zeros((6, 2))
        B[2:4, :] = I2  # v' = a + ...
        G = np.zeros((6, 4))
        G[2:4, 0:2] = I2  # v' = ... + w1
        G[4:6, 2:4] = I2  # w2' = ... + sqrt(2 beta) sigma_w eps
        q_w1 = sigma_w**2 * self.params.w1_psd_time_s  # m^2/s^3
        q_w2 = 2.0 * beta * sigma_w**2  # m^2/s^5
        Qc = np.diag([q_w1, q_w1, q_w2, q_w2])
        return A, B, G, Qc

    @staticmethod
    def gravity_acceleration(Z_gnd_table: np.ndarray) -> np.ndarray:
        """In-plane acceleration a (2,) m/s^2 of a ball rolling without slipping.

        ``Z_gnd_table`` is the world's up axis in the table frame (geometry.up_in_table);
        a = -(5/7) g Z_gnd,table[x, y]: the ball accelerates toward the lower side.
        """
        Z = np.asarray(Z_gnd_table, dtype=float)
        return -ROLLING_ACCEL_FACTOR * GRAVITY_MPS2 * Z[:2]

    @staticmethod
    def clamp_to_border(
        x: np.ndarray, P: np.ndarray | None = None, limit_m: float = BALL_TRAVEL_M
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Border constraint (spec): a position beyond +-``limit_m`` (L/2 - r) is clamped
        there and that axis's velocity zeroed (fully inelastic collision).

        Returns (x', P'): x' a new array, P' the given P itself: clamping projects the
        estimate onto the feasible square, which holds the true position, so the position
        error cannot grow, and keeping P is the conservative choice. (Returning P itself
        keeps a converged KalmanFilter on its converged-gain path.)
        """
        x = np.array(x, dtype=float)
        for axis in (0, 1):
            if abs(x[axis]) > limit_m:
                x[axis] = np.copysign(limit_m, x[axis])
                x[2 + axis] = 0.0
        return x, P

    def predict_ahead(
        self,
        x: np.ndarray,
        n_steps: int,
        dt_s: float,
        u: np.ndarray,
        limit_m: float = BALL_TRAVEL_M,
    ) -> np.ndarray:
        """Mean N-step-ahead prediction x(k+1..k+N | k), shape (n_steps, 6).

        ``u`` is the acceleration a (2,), held for all steps, or one per step
        (n_steps, 2). The border clamp is applied after every step (spec: 10 steps drawn
        in the report, meant for predictive control).
        """
        Phi, Gamma, _ = self.matrices(dt_s)
        u = np.asarray(u, dtype=float)
        inputs = np.broadcast_to(u, (n_steps, 2))
        out = np.empty((n_steps, 6))
        state = np.asarray(x, dtype=float)
        for k in range(n_steps):
            state, _ = self.clamp_to_border(Phi @ state + Gamma @ inputs[k], limit_m=limit_m)
            out[k] = state
        return out


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
        self.C = _readonly(C)

    def continuous(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(A, B, G, Qc) of x' = A x + B a + G w."""
        d, eye = self.dim, np.eye(self.dim)
        A = np.zeros((2 * d, 2 * d))
        A[:d, d:] = eye
        B = np.zeros((2 * d, d))
        B[d:, :] = eye
        return A, B, B.copy(), self.accel_std**2 * eye


class TiltLagModel(LinearModel):
    """The arm's tilt tracking: a first-order lag from the commanded tilt to the table's.

    The arm's joint motors close the fraction k_p of their error every physics step
    (envs/robots/kuka_iiwa.py), so a held command u is followed as
    theta(t) = u + (theta(0) - u) exp(-t / tau) with tau = -dt_physics / ln(1 - k_p)
    (about 38 ms for BallTable's defaults). State theta (``dim`` angles, rad), input u (the
    command, rad); w white on the rate with intensity ``rate_noise_std``^2 x 1 s covers IK
    and coupling errors: theta' = (u - theta) / tau + w. The rate follows from the state
    and the command: theta' = (u - theta) / tau.
    """

    def __init__(self, time_constant_s: float, rate_noise_std: float, dim: int = 2) -> None:
        if not (np.isfinite(time_constant_s) and time_constant_s > 0.0):
            raise ValueError(f"TiltLagModel: time_constant_s = {time_constant_s!r}, must be > 0")
        if not (np.isfinite(rate_noise_std) and rate_noise_std >= 0.0):
            raise ValueError(f"TiltLagModel: rate_noise_std = {rate_noise_std!r}, must be >= 0")
        self.tau_s = float(time_constant_s)
        self.rate_noise_std = float(rate_noise_std)
        self.dim = self.n = int(dim)
        self.C = _readonly(np.eye(self.dim))

    @classmethod
    def from_arm(
        cls, position_gain: float, physics_dt_s: float, rate_noise_std: float, dim: int = 2
    ) -> TiltLagModel:
        """The lag of an arm whose joint motors have gain k_p at the physics step dt."""
        if not 0.0 < position_gain < 1.0:
            raise ValueError(f"TiltLagModel: position_gain = {position_gain!r}, must be in (0, 1)")
        return cls(-physics_dt_s / np.log(1.0 - position_gain), rate_noise_std, dim)

    def continuous(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(A, B, G, Qc) of theta' = A theta + B u + G w."""
        eye = np.eye(self.dim)
        return -eye / self.tau_s, eye / self.tau_s, eye, self.rate_noise_std**2 * eye

    def rate(self, theta: np.ndarray, u: np.ndarray) -> np.ndarray:
        """theta' = (u - theta) / tau."""
        return (np.asarray(u) - np.asarray(theta)) / self.tau_s


class BallisticModel(LinearModel):
    """A ball in free flight without air drag (spec/catcher.md (19)-(20)), world frame z up.

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
        self.u = _readonly(np.ones(1))  # (20): u(kh) = 1

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
        return _readonly(Phi), _readonly(Gamma), _readonly(Q)
