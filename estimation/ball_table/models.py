"""BallTable's process models (docs/spec/table_ball.md "Dynamics and estimator").

- :class:`RollingBallModel`: the ball rolling on the tilted table, both axes.
- :class:`TiltLagModel`: the arm's first-order lag from commanded to actual tilt.

All matrices are read-only arrays (cached per time step; copy before modifying).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from observer_gym.envs.ball_table.geometry import BALL_RADIUS_M, BALL_TRAVEL_M
from observer_gym.envs.sim import GRAVITY_MPS2
from observer_gym.estimation.models import LinearModel, readonly

__all__ = [
    "BALL_CENTRE_HEIGHT_M",
    "KF_ROTATION_HEIGHTS_M",
    "ROLLING_ACCEL_FACTOR",
    "RollingBallModel",
    "RollingBallParams",
    "TiltLagModel",
]

# A solid sphere rolling without slipping: a = (5/7) g sin(theta) (docs/spec/table_ball.md).
ROLLING_ACCEL_FACTOR = 5.0 / 7.0
# The ball's centre above the table's rotation axis: the arm tilts the table about the
# centre of its top surface (envs/ball_table/scene.py, command_tilt; table.urdf's frame),
# and the ball's centre rests one radius above it.
BALL_CENTRE_HEIGHT_M = BALL_RADIUS_M
# kf's heights (tilt_x axis, tilt_y axis) of the ball's centre above the axes the table
# turns about as the arm drives it: the ball's radius, and 18.6 mm more about y, where the
# ball's x error over a step is -18.6 mm times the tilt_y angular acceleration
# (least squares over 10 episodes of the LQR; the arm's joints lag, so the table's centre
# swings as it turns; ``python benchmarks/ball_table_model_error.py``).
KF_ROTATION_HEIGHTS_M = BALL_CENTRE_HEIGHT_M + np.array([0.0, 0.017])
KF_ROTATION_HEIGHTS_M.flags.writeable = False


@dataclass(frozen=True)
class RollingBallParams:
    """Noise parameters of :class:`RollingBallModel` (docs/spec/table_ball.md).

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
    """The BallTable estimator model, both table axes (docs/spec/table_ball.md).

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
        self.C = readonly(C)
        self.R = readonly(self.params.sigma_v_m**2 * np.eye(2))

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
    def rotation_increment(
        rate_before: np.ndarray,
        rate_after: np.ndarray,
        tilt_change: np.ndarray,
        dt_s: float,
        height_m: float | np.ndarray = BALL_CENTRE_HEIGHT_M,
    ) -> np.ndarray:
        """What the table's angular acceleration adds to the state (6,) over an interval.

        The ball's centre rides ``height_m`` (h) above the table's rotation axis. Per
        tilt axis, the Lagrangian of a ball rolling without slipping on a plane turning by
        theta about an axis in it gives (7/5)(p'' - h theta'') = -g sin(theta) + p
        theta'^2: the angular acceleration moves the ball as h theta'' in full (not 5/7 of
        it). In the table frame, with (theta_x, theta_y) the tilts (geometry.py): p_x'' =
        -h theta_y'', p_y'' = +h theta_x'' (a positive tilt_y lowers the +x side).
        Integrated over the interval from the rate just before it (``rate_before``) to
        the rate at its end (``rate_after``) with the tilt moving by ``tilt_change``:
        dv = h (rate_after - rate_before) and dp = h (tilt_change - rate_before dt), each
        with the axes' signs; w is untouched. ``height_m`` is h, or h per tilt axis (2,)
        (:data:`KF_ROTATION_HEIGHTS_M`). (The table's translation, when the arm's joints
        lag, and the centrifugal p theta'^2 are left out.)
        """
        dv = height_m * (np.asarray(rate_after, float) - np.asarray(rate_before, float))
        dp = height_m * (np.asarray(tilt_change, float) - np.asarray(rate_before, float) * dt_s)
        return np.array([-dp[1], dp[0], -dv[1], dv[0], 0.0, 0.0])

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


class TiltLagModel(LinearModel):
    """The arm's tilt tracking: a first-order lag from the commanded tilt to the table's.

    The arm's joint motors close the fraction k_p of their error every physics step
    (envs/robots/kuka_iiwa.py), so a held command u is followed as
    theta(t) = u + (theta(0) - u) exp(-t / tau) with tau = -dt_physics / ln(1 - k_p)
    (about 38 ms for BallTable's defaults). State theta (``dim`` angles, rad), input u (the
    command, rad); w white on the rate with intensity ``rate_noise_std``^2 x 1 s covers IK
    and coupling errors: theta' = (u - theta) / tau + w.

    The rate follows from the state and the command, theta' = g (u - theta): g = 1 / tau
    for the continuous lag; for an arm (:meth:`from_arm`) the rate the simulator reports is
    its last physics step's velocity, k_p (u - theta_before) / dt with theta = theta_before
    + k_p (u - theta_before), so g = k_p / ((1 - k_p) dt), 5.5 % more than 1 / tau at
    k_p = 0.1 (measured: the reported rate is 1.053-1.055 times (u - theta) / tau).
    """

    def __init__(
        self,
        time_constant_s: float,
        rate_noise_std: float,
        dim: int = 2,
        rate_gain_per_s: float | None = None,
    ) -> None:
        if not (np.isfinite(time_constant_s) and time_constant_s > 0.0):
            raise ValueError(f"TiltLagModel: time_constant_s = {time_constant_s!r}, must be > 0")
        if not (np.isfinite(rate_noise_std) and rate_noise_std >= 0.0):
            raise ValueError(f"TiltLagModel: rate_noise_std = {rate_noise_std!r}, must be >= 0")
        self.tau_s = float(time_constant_s)
        self.rate_gain_per_s = 1.0 / self.tau_s if rate_gain_per_s is None else rate_gain_per_s
        self.rate_noise_std = float(rate_noise_std)
        self.dim = self.n = int(dim)
        self.C = readonly(np.eye(self.dim))

    @classmethod
    def from_arm(
        cls, position_gain: float, physics_dt_s: float, rate_noise_std: float, dim: int = 2
    ) -> TiltLagModel:
        """The lag of an arm whose joint motors have gain k_p at the physics step dt."""
        if not 0.0 < position_gain < 1.0:
            raise ValueError(f"TiltLagModel: position_gain = {position_gain!r}, must be in (0, 1)")
        # tau = -dt / ln(1 - k_p); the reported rate's gain g = k_p / ((1 - k_p) dt)
        tau_s = -physics_dt_s / np.log(1.0 - position_gain)
        gain = position_gain / ((1.0 - position_gain) * physics_dt_s)
        return cls(tau_s, rate_noise_std, dim, rate_gain_per_s=gain)

    def continuous(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(A, B, G, Qc) of theta' = A theta + B u + G w."""
        eye = np.eye(self.dim)
        return -eye / self.tau_s, eye / self.tau_s, eye, self.rate_noise_std**2 * eye

    def rate(self, theta: np.ndarray, u: np.ndarray) -> np.ndarray:
        """theta' = g (u - theta) (see the class docstring)."""
        return (np.asarray(u) - np.asarray(theta)) * self.rate_gain_per_s
