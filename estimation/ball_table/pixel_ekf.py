"""The BallTable observer ``ekf``: one extended Kalman filter straight from the pixels, with
no PnP in between.

State (14): the ball's position, velocity and Gauss-Markov disturbance per table axis
(RollingBallModel's six), the table's two tilt angles (TiltLagModel's) and its centre's
offset from TABLE_CENTRE_HOME_WORLD in the world frame in two parts of three: a constant
(where a camera calibration error makes the table appear: its prior the declared
calibration uncertainty through :func:`centre_calibration_cov`, none without one) and the
arm's (a Gauss-Markov with the stationary std and correlation measured once,
TABLE_CENTRE_HOLD_STD_M, benchmarks/ball_table_centre_motion.py: the arm's joints lag, so
the centre moves 0.14 mm RMS, up to 1.7 mm). The estimate is the env's state layout;
the centre's states are internal. Process: the tilt follows the commanded tilt through
the arm's first-order lag; the ball rolls with the gravity input of the tilt at the middle
of the interval (the trapezoid of its two ends, as ``kf`` has it), so the ball's
prediction depends on the tilt and F couples them:

    theta' = Phi_t theta + Gamma_t u,   b' = Phi_b b + Gamma_b a((theta + theta') / 2)
    F = [[Phi_b, Gamma_b A (I + Phi_t) / 2], [0, Phi_t]],   A = da/dtheta

and the tilt's process noise reaches the ball the same way (Q). The border constraint is
applied to the predicted mean, as in ``kf``.

Measurement: the pixels of the table's corners and of the ball's centre, predicted
through the frame's nominal camera (``K``, ``T_world_cam`` in ``info["frames"]``) from the
table's pose, which the tilt angles and the centre give (``T_world_table`` =
[R_x(tilt_x) R_y(tilt_y), TABLE_CENTRE_HOME_WORLD + offset]: the arm tilts the table
about its centre, envs/ball_table/scene.py), and the ball's centre on the table at
its radius, (x, y, r) in the table frame. A camera pose error shifts and scales the whole
image: the centre's constant part takes what a translation of the table explains (7 mm
at 1 degree of rotation error, 7.7 mm of depth at 2 % focal error), and the offset it
leaves on the tilt and the ball's position (about the rotation error itself on the tilt)
is reported, not filtered: :func:`fit_calibration_cov` gives its covariance as this
model reads the frame, which the observer adds to the covariance it reports.

The ball's pixel is the centre of the sphere's exact image ellipse (what the env's
measurement and the image stage's blob centroid report), which for a sphere of centre S
(camera frame) and radius r is the pinhole projection of S scaled by S_z^2 / (S_z^2 -
r^2): see :func:`project`. Measured corners are those of the red top (measurements mode;
from rgb, the image stage's corners of the model it found) and, from rgb, the borders'
outer outline beside them. A corner with a
non-finite pixel is dropped from that step's measurement vector; a table not found gives
no corner rows, a ball not found no ball rows.

The corners update the filter first, without a gate (as ``kf``'s tilt filter); the ball's
pixel then updates it behind a chi-square gate, linearised again after the corners'
update (for a linear model the same as one joint update: the two noises are
independent). After ``reacquire_after`` consecutive rejections, and when the ball is seen
for the first time, its position is set from its pixel (the geometry stage's ray to the
ball's centre, met with the plane z = r of the estimated table) and its velocity and
disturbance restarted, their correlations with the tilt dropped.

Each frame is fused at its capture time (as ``kf-latency``, through
:class:`~observer_gym.estimation.latency.CaptureTimeFusion`) and the estimate predicted to
the step's time. The table's angular acceleration moves the ball about the arm's axes as
in ``kf``'s model, the tilt_y axis 17 mm below the top (ROTATION_HEIGHTS_M, models.
KF_ROTATION_HEIGHTS_M): without it, at 0.1 s of latency, the LQR on this estimate swung
in a limit cycle (24 mm from the centre, 31 mrad RMS tilt; 9.2 mm and 14 mrad with it),
the unmodelled swing read as the table centre's motion (docs/your_method.md). In
measurements mode, unless a calibration error is declared, the ball's process noise is
kf's measured model error (a floor and terms that follow the table's motion; noise.py,
"Q"), not sigma_w = 0.5 m/s^2 at every step: predicted over a frame's age that constant
claimed five to ten times the error (NEES/dof 0.10-0.17 at 0-0.15 s of latency with
jitter; 0.52-0.61 with kf's; docs/results/consistency.md, "Latency with jitter").

Pixel noise: from rgb, the image stage's measured errors (corners of the red top 0.18-0.31
px RMS, outline 0.15 px, ball centre 0.06 px on 400 rendered frames, fixed camera and head
motion; the red top's taken at 0.25 px, the middle of its corners'), the noise rule's
detector error model (median episode NEES/dof 0.46 from rendered frames,
tests/estimation/test_consistency_ball_table.py). From rgb the arm's part of the centre
is left out (its std 0): with it the ball's position error from rendered frames grew
from 0.17 to 0.29 mm and its NEES (4 dof) from 2.0 to 4.6 (tests/estimation/
test_ball_table_observers.py, 6 s): the filter moved the centre after the image stage's
corner errors, which it takes as white and which likely are not (the same pose, the
same edges); the arm's 0.14 mm (0.05 px) is well inside their 0.25 px. In measurements
mode the declared pixel noise (``SensorSpec.measurement_noise_std_px``, the noise rule of
estimation/ball_table/noise.py) with a floor of MEASUREMENT_FLOOR_PX for what the model
leaves out: the corners depart from it at the true tilt and centre by 0.001 px RMS,
0.005 px at the 99th percentile (float32 pixels; the table's small yaw under the arm),
and the floor lies between them (before the model had the centre's offset it was 0.05
px: the table's departure from a centre held at home, 0.052 px RMS).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from observer_gym.envs.ball_table import STATE_DIM, BallTableEnv
from observer_gym.envs.ball_table import geometry as geo
from observer_gym.envs.sensor import SensorSpec
from observer_gym.envs.sim import GRAVITY_MPS2
from observer_gym.estimation.ball_table.features import (
    BORDER_OUTLINE,
    RED_TOP,
    BallTableFeatures,
)
from observer_gym.estimation.ball_table.frames import FrameReader
from observer_gym.estimation.ball_table.fusion import Fused, FusedObserver
from observer_gym.estimation.ball_table.geometry_stage import BallTableDetector, model_corners_table
from observer_gym.estimation.ball_table.models import (
    KF_ROTATION_HEIGHTS_M,
    ROLLING_ACCEL_FACTOR,
    RollingBallModel,
    TiltLagModel,
)
from observer_gym.estimation.ball_table.noise import (
    KF_ACCEL_FLOOR_MPS2,
    BallTableNoiseRule,
    ball_process_params,
)
from observer_gym.estimation.ball_table.observer import (
    RGB_BALL_STD_M,
    BallTableObserverParams,
    motion_model_error_q,
    tilt_covariance_blocks,
)
from observer_gym.estimation.calibration import calibration_covariance, calibration_variances
from observer_gym.estimation.ekf import ExtendedKalmanFilter
from observer_gym.estimation.filter_copy import copy_filter
from observer_gym.estimation.gating import ChiSquareGate
from observer_gym.estimation.r_scale import checked_r_scale

__all__ = ["PixelEKFObserver", "PixelEKFParams", "PixelMeasurement", "project"]

BALL = slice(0, 6)  # the ball's states in the EKF's state
POS = slice(0, 2)
VEL = slice(2, 4)
TILT = slice(6, 8)
# The table centre's offset from its home, world frame (m), in two parts: where the
# declared calibration error puts it (constant) and the arm's (Gauss-Markov).
CENTRE = slice(8, 11)
ARM = slice(11, 14)
N_STATES = 14
MEASUREMENT_FLOOR_PX = 0.003
ROTATION_HEIGHTS_M = KF_ROTATION_HEIGHTS_M
# The table centre's motion under the arm (world x, y, z), measured with
# ``python benchmarks/ball_table_centre_motion.py`` (the LQR on the truth, pushes at 0.5
# Hz, 10 episodes of 500 steps): its offset from home has RMS 0.137, 0.012 and 0.099 mm
# (the Gauss-Markov's stationary std) and lag-one correlation 0.91, 0.81 and 0.91 over
# a 20 ms step (its correlation time); the change over a step that these give,
# sqrt(2 (1 - rho)) std, is 0.058, 0.0074 and 0.042 mm (measured 0.057, 0.0076, 0.041).
TABLE_CENTRE_HOLD_STD_M = np.array([1.37e-4, 1.2e-5, 9.9e-5])
TABLE_CENTRE_CORRELATION_PER_STEP = np.array([0.91, 0.81, 0.91])
TABLE_CENTRE_STEP_S = 0.02
# From rgb: the image stage's measured pixel errors (see the module docstring).
RGB_STD_PX = {RED_TOP: 0.25, BORDER_OUTLINE: 0.15, "ball": 0.06}


@dataclass(frozen=True)
class PixelEKFParams:
    """``ekf``'s parameters: the process noise, priors, gate and re-acquisition of ``kf``'s
    (``filters``; its ``tilt_meas_std_rad`` and ``converged_rtol`` are not used here) and
    the pixel noise std of each kind of feature (None: the default of the module
    docstring)."""

    filters: BallTableObserverParams = field(default_factory=BallTableObserverParams)
    corner_std_px: float | None = None
    outline_std_px: float | None = None
    ball_std_px: float | None = None


@dataclass(frozen=True)
class PixelMeasurement:
    """One frame's pixels for the EKF: the seen corners (table frame (n, 3), pixels (n, 2),
    noise std (n,)), the ball's image (u, v, semi-major radius) or None and its centre's
    noise std, and the frame's nominal calibration."""

    K: np.ndarray
    T_world_cam: np.ndarray
    corners_table: np.ndarray
    corners_px: np.ndarray
    corner_std_px: np.ndarray
    ball_px: np.ndarray | None
    ball_std_px: float


def project(
    K: np.ndarray, T_world_cam: np.ndarray, points_world: np.ndarray, radius_m: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (n, 2) of world points (n, 3) and their Jacobians d(u, v)/d(point) (n, 2, 3).

    With ``radius_m`` r > 0 the points are sphere centres and the pixel is the centre of
    the sphere's exact image ellipse: for the centre S in the camera frame, the normalised
    image conic's centre (envs.camera.sphere_image) works out to (S_x, S_y) S_z / (S_z^2 -
    r^2), i.e. the pinhole projection scaled by S_z^2 / (S_z^2 - r^2); r = 0 is the pinhole
    projection itself.
    """
    R_world_cam, t_world_cam = T_world_cam[:3, :3], T_world_cam[:3, 3]
    # S = R_world_cam^T (p - t_world_cam): the points in the camera frame
    S = (np.asarray(points_world, dtype=float) - t_world_cam) @ R_world_cam
    sx, sy, sz = S[:, 0], S[:, 1], S[:, 2]
    r2 = radius_m * radius_m
    # g = S_z / (S_z^2 - r^2),  dg/dS_z = -(S_z^2 + r^2) / (S_z^2 - r^2)^2
    denominator = sz * sz - r2
    g = sz / denominator
    dg = -(sz * sz + r2) / (denominator * denominator)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    # u = fx S_x g + cx,  v = fy S_y g + cy
    uv = np.column_stack([fx * sx * g + cx, fy * sy * g + cy])
    d_uv_d_S = np.zeros((S.shape[0], 2, 3))
    d_uv_d_S[:, 0, 0] = fx * g
    d_uv_d_S[:, 0, 2] = fx * sx * dg
    d_uv_d_S[:, 1, 1] = fy * g
    d_uv_d_S[:, 1, 2] = fy * sy * dg
    return uv, d_uv_d_S @ R_world_cam.T  # dS/dp = R_world_cam^T


def _tilt_rotation_and_derivatives(tilt_x: float, tilt_y: float):
    """R = R_x(tilt_x) R_y(tilt_y) and dR/dtilt_x, dR/dtilt_y."""
    cx, sx, cy, sy = math.cos(tilt_x), math.sin(tilt_x), math.cos(tilt_y), math.sin(tilt_y)
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]])
    dRx = np.array([[0.0, 0.0, 0.0], [0.0, -sx, -cx], [0.0, cx, -sx]])
    Ry = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    dRy = np.array([[-sy, 0.0, cy], [0.0, 0.0, 0.0], [-cy, 0.0, -sy]])
    return Rx @ Ry, dRx @ Ry, Rx @ dRy


def gravity_jacobian(tilt_x: float, tilt_y: float) -> np.ndarray:
    """da/d(tilt_x, tilt_y) (2, 2) of RollingBallModel.gravity_acceleration(up_in_table):
    a = (5/7) g (sin(tilt_y) cos(tilt_x), -sin(tilt_x))."""
    k = ROLLING_ACCEL_FACTOR * GRAVITY_MPS2
    cx, sx, cy, sy = math.cos(tilt_x), math.sin(tilt_x), math.cos(tilt_y), math.sin(tilt_y)
    return k * np.array([[-sy * sx, cy * cx], [-cx, 0.0]])


def table_centre_world(x: np.ndarray) -> np.ndarray:
    """The table's centre in the world for the state ``x``: its home plus the offset."""
    return geo.TABLE_CENTRE_HOME_WORLD + x[CENTRE] + x[ARM]


def corner_pixels(x: np.ndarray, m: PixelMeasurement) -> tuple[np.ndarray, np.ndarray]:
    """h and H of the corners' pixels (2n,), (2n, N_STATES) at the state ``x``."""
    R, dR_dx, dR_dy = _tilt_rotation_and_derivatives(x[6], x[7])
    q = m.corners_table
    # p_i = c + R(tilt) q_i,  dp_i/dtilt = dR/dtilt q_i,  dp_i/dc = I
    uv, J = project(m.K, m.T_world_cam, q @ R.T + table_centre_world(x))
    n = q.shape[0]
    H = np.zeros((2 * n, N_STATES))
    H[:, 6] = np.einsum("kij,kj->ki", J, q @ dR_dx.T).reshape(-1)
    H[:, 7] = np.einsum("kij,kj->ki", J, q @ dR_dy.T).reshape(-1)
    H[:, CENTRE] = H[:, ARM] = J.reshape(2 * n, 3)
    return uv.reshape(-1), H


def ball_pixel(x: np.ndarray, m: PixelMeasurement) -> tuple[np.ndarray, np.ndarray]:
    """h and H of the ball's centre pixel (2,), (2, N_STATES) at the state ``x``."""
    R, dR_dx, dR_dy = _tilt_rotation_and_derivatives(x[6], x[7])
    # the ball's centre p = c + R(tilt) (x, y, r): dp/d(x, y) = R[:, :2], dp/dtilt = dR/dtilt q,
    # dp/dc = I
    q = np.array([x[0], x[1], geo.BALL_RADIUS_M])
    centre = R @ q + table_centre_world(x)
    uv, J = project(m.K, m.T_world_cam, centre[None], geo.BALL_RADIUS_M)
    J = J[0]
    H = np.zeros((2, N_STATES))
    H[:, POS] = J @ R[:, :2]
    H[:, 6] = J @ (dR_dx @ q)
    H[:, 7] = J @ (dR_dy @ q)
    H[:, CENTRE] = H[:, ARM] = J
    return uv[0], H


def T_world_table(tilt: np.ndarray, centre_offset_world_m: np.ndarray | None = None) -> np.ndarray:
    """The table's pose for the tilt angles and its centre's offset from home (None: the
    arm holds it at home)."""
    T = np.eye(4)
    T[:3, :3] = geo.tilt_rotation(float(tilt[0]), float(tilt[1]))
    T[:3, 3] = geo.TABLE_CENTRE_HOME_WORLD
    if centre_offset_world_m is not None:
        T[:3, 3] += centre_offset_world_m
    return T


def centre_calibration_cov(
    sensor: SensorSpec, K: np.ndarray, T_world_cam: np.ndarray
) -> np.ndarray | None:
    """The declared calibration uncertainty's covariance (3, 3) of where the table's home
    centre appears to be (world frame), None without calibration error: the point the
    nominal camera (``K``, ``T_world_cam``) sees at the centre's pixel and depth, placed
    again through a camera moved along each calibration parameter
    (estimation/calibration.py). Its depth follows the focal length, as a square of known
    size does: z = z_0 fx / fx_0."""
    variances = calibration_variances(sensor)
    if not variances:
        return None
    K0, T0 = np.asarray(K, dtype=float), np.asarray(T_world_cam, dtype=float)
    # S_0 = T0^-1 c_home: the home centre in the nominal camera's frame, its pixel uv_0
    S0 = (geo.TABLE_CENTRE_HOME_WORLD - T0[:3, 3]) @ T0[:3, :3]
    uv1 = K0 @ (S0 / S0[2])

    def apparent(K_: np.ndarray, T_: np.ndarray) -> np.ndarray:
        # S = z_0 (fx / fx_0) K^-1 (u_0, v_0, 1),  p = T S
        S = S0[2] * (K_[0, 0] / K0[0, 0]) * np.linalg.solve(K_, uv1)
        return T_[:3, :3] @ S + T_[:3, 3]

    return calibration_covariance(apparent, K0, T0, variances)


FIT = [0, 1, 6, 7, 8, 9, 10]  # the states a frame's pixels place: ball, tilt, centre


def fit_calibration_cov(
    x: np.ndarray, m: PixelMeasurement, variances: dict[str, float]
) -> np.ndarray | None:
    """The declared calibration uncertainty's covariance (4, 4) of the offset it puts on
    (tilt, ball position) as the EKF's own pixel model reads this frame: the weighted
    least-squares fit of the ball's position, the tilt and the centre to the corners' and
    the ball's pixels, one Gauss-Newton step from ``x``, through a camera moved along each
    calibration parameter (estimation/calibration.py). None without ``variances``, a ball
    or three corners (the fit needs them). The PnP pipelines' offset (the noise rule's) is
    not the EKF's: on BallTable's 160 px focal length the tilt is weakly held by the
    corners, and under 2 % focal error this model's least-squares fit to one frame's
    corners settles 3.8 mrad off in tilt (every corner within 0.05 px) where PnP's tilt
    moves by 0.01 mrad."""
    if not variances or m.ball_px is None or m.corners_px.shape[0] < 3:
        return None
    h_c, H_c = corner_pixels(x, m)
    h_b, H_b = ball_pixel(x, m)
    H = np.vstack([H_c, H_b])[:, FIT]
    weights = np.concatenate([np.repeat(m.corner_std_px, 2), [m.ball_std_px] * 2]) ** -2.0
    # the fit's change for a change dh of the predicted pixels (the real pixels fixed):
    # d(ball, tilt, centre) = -(H^T W H)^-1 H^T W dh
    HtW = H.T * weights
    gain = np.linalg.solve(HtW @ H, HtW)
    K0, T0 = m.K, m.T_world_cam

    def fitted(K_: np.ndarray, T_: np.ndarray) -> np.ndarray:
        moved = PixelMeasurement(
            K_, T_, m.corners_table, m.corners_px, m.corner_std_px, m.ball_px, m.ball_std_px
        )
        dh = np.concatenate([corner_pixels(x, moved)[0] - h_c, ball_pixel(x, moved)[0] - h_b])
        d = -gain @ dh
        return np.concatenate([d[2:4], d[0:2]])  # (tilt, ball position)

    return calibration_covariance(fitted, K0, T0, variances)


class PixelEKF:
    """The EKF as a :class:`~observer_gym.estimation.latency.FilterCore` (see the module
    docstring); a measurement is a :class:`~observer_gym.estimation.ball_table.observer.
    Fused` of a :class:`PixelMeasurement`."""

    def __init__(
        self,
        params: BallTableObserverParams,
        ball_model: RollingBallModel,
        tilt_model: TiltLagModel,
        detector: BallTableDetector,
        time_s: float,
        centre_calibration: np.ndarray | None = None,
        arm_std_m: np.ndarray = TABLE_CENTRE_HOLD_STD_M,
    ) -> None:
        self.params = params
        self.arm_std_m = np.asarray(arm_std_m, dtype=float)
        self.ball_model = ball_model
        self.tilt_model = tilt_model
        self.detector = detector
        self.time_s = time_s
        self.tilt_cmd = np.zeros(2)  # the arm is commanded level at reset
        # the tilt the lag model makes from the commands alone: the rotation term's rates
        # come from it, free of the tilt estimate's noise and of a calibration error's bias
        # (as kf's, estimation/ball_table/observer.py)
        self._lag_tilt = np.zeros(2)
        self.ball_seen = False
        self.rejections_in_a_row = 0
        self.reacquisitions = 0
        self._gate = ChiSquareGate(probability=params.gate_probability)
        p = params
        P0 = np.diag(
            [p.start_pos_std_m**2] * 2
            + [p.start_speed_std_mps**2] * 2
            + [p.ball.sigma_w**2] * 2
            + [p.start_tilt_std_rad**2] * 2
            + [0.0] * 3
            + list(self.arm_std_m**2)
        )
        # the centre's prior: the arm's part at its stationary std, the constant part where
        # the declared calibration puts it (none without calibration error: it stays 0)
        if centre_calibration is not None:
            P0[CENTRE, CENTRE] += centre_calibration
        self.ekf = ExtendedKalmanFilter(np.zeros(N_STATES), P0)

    # --- FilterCore ---------------------------------------------------------------------
    def predict_to(self, time_s: float, action: np.ndarray | None) -> None:
        dt_s = round(time_s - self.time_s, 9)  # to the nanosecond, as kf's
        if dt_s <= 0.0:
            return
        x = self.ekf.x
        tilt_model = self.tilt_model
        lag_before = self._lag_tilt
        rate_before = tilt_model.rate(lag_before, self.tilt_cmd)  # before the new command
        if action is not None:
            self.tilt_cmd = np.asarray(action, dtype=float)
        Phi_t, Gamma_t, Q_t = tilt_model.matrices(dt_s)
        Phi_b, Gamma_b, Q_b = self.ball_model.matrices(dt_s)
        # theta' = Phi_t theta + Gamma_t u;  c' = c (the calibration's part is constant)
        tilt_next = Phi_t @ x[TILT] + Gamma_t @ self.tilt_cmd
        # b' = Phi_b b + Gamma_b a((theta + theta') / 2) + the table's angular
        # acceleration's increment (as kf's), clamped at the border
        mid = 0.5 * (x[TILT] + tilt_next)
        accel = self.ball_model.gravity_acceleration(geo.up_in_table(mid[0], mid[1]))
        self._lag_tilt = Phi_t @ lag_before + Gamma_t @ self.tilt_cmd
        rate_after = tilt_model.rate(self._lag_tilt, self.tilt_cmd)
        turned = self.ball_model.rotation_increment(
            rate_before, rate_after, self._lag_tilt - lag_before, dt_s, ROTATION_HEIGHTS_M
        )
        if self.params.measured_model_error:  # kf's, following the table's motion
            Q_b = Q_b + motion_model_error_q(self.ball_model, dt_s, rate_before, rate_after)
        ball_next, _ = self.ball_model.clamp_to_border(Phi_b @ x[BALL] + Gamma_b @ accel + turned)
        # d(ball')/d(mid tilt); d(mid)/d(theta) = (I + Phi_t) / 2; the tilt's noise w
        # enters mid as w / 2 (first order), hence Q's coupled part. The rotation term is
        # an input (from the commands), not a function of the state.
        ball_per_mid = Gamma_b @ gravity_jacobian(mid[0], mid[1])
        F = np.zeros((N_STATES, N_STATES))
        F[BALL, BALL] = Phi_b
        F[TILT, TILT] = Phi_t
        F[BALL, TILT] = ball_per_mid @ (0.5 * (np.eye(2) + Phi_t))
        F[CENTRE, CENTRE] = np.eye(3)
        # the arm's part: a' = rho a + w,  rho = rho_step^(dt / step),
        # var(w) = std^2 (1 - rho^2) (its stationary std unchanged)
        rho = TABLE_CENTRE_CORRELATION_PER_STEP ** (dt_s / TABLE_CENTRE_STEP_S)
        F[ARM, ARM] = np.diag(rho)
        G = np.vstack([0.5 * ball_per_mid, np.eye(2)])
        Q = np.zeros((N_STATES, N_STATES))
        Q[:8, :8] = G @ Q_t @ G.T
        Q[BALL, BALL] += Q_b
        Q[ARM, ARM] = np.diag(self.arm_std_m**2 * (1.0 - rho**2))
        self.ekf.predict_nonlinear(
            np.concatenate([ball_next, tilt_next, x[CENTRE], rho * x[ARM]]), F, Q
        )
        self.time_s = time_s

    def update(self, measurement: Fused) -> bool:
        m: PixelMeasurement = measurement.value
        measurement.clear_nis()
        used = False
        if m.corners_px.shape[0]:
            h, H = corner_pixels(self.ekf.x, m)
            R = np.diag(np.repeat(np.square(m.corner_std_px), 2))
            self.ekf.gate = None  # the corners are not gated (kf's tilt filter is not)
            result = self.ekf.update_nonlinear(m.corners_px.reshape(-1), h, H, R)
            if result.accepted:
                measurement.add_nis(result.nis, h.shape[0])
            used = result.accepted
        if m.ball_px is not None:
            used |= self._update_ball(m, measurement)
        return used

    def snapshot(self) -> tuple:
        return (
            self.time_s,
            self.tilt_cmd,
            copy_filter(self.ekf),
            self.ball_seen,
            self.rejections_in_a_row,
            self.reacquisitions,
            self._lag_tilt,
        )

    def restore(self, snapshot: tuple) -> None:
        time_s, tilt_cmd, ekf, seen, rejections, reacquisitions, lag_tilt = snapshot
        self.time_s, self.tilt_cmd, self.ekf = time_s, tilt_cmd, copy_filter(ekf)
        self._lag_tilt = lag_tilt
        self.ball_seen, self.rejections_in_a_row = seen, rejections
        self.reacquisitions = reacquisitions

    # --- the ball -----------------------------------------------------------------------
    def _update_ball(self, m: PixelMeasurement, measurement: Fused) -> bool:
        if not self.ball_seen:
            self.ball_seen = self._restart_ball(m)
            return self.ball_seen
        assert m.ball_px is not None  # update() calls this only with the ball seen
        h, H = ball_pixel(self.ekf.x, m)
        R = np.eye(2) * m.ball_std_px**2
        self.ekf.gate = self._gate
        result = self.ekf.update_nonlinear(m.ball_px[:2], h, H, R)
        if result.accepted:
            measurement.add_nis(result.nis, 2)
        self.rejections_in_a_row = 0 if result.accepted else self.rejections_in_a_row + 1
        if self.rejections_in_a_row >= self.params.reacquire_after:
            self.rejections_in_a_row = 0
            if self._restart_ball(m):
                self.reacquisitions += 1
                return True
        return result.accepted

    def _restart_ball(self, m: PixelMeasurement) -> bool:
        """Set the ball's position from its pixel on the estimated table (velocity and
        disturbance from their priors, uncorrelated with the tilt); False when its ray
        misses the table."""
        x = self.ekf.x
        offset = table_centre_world(x) - geo.TABLE_CENTRE_HOME_WORLD
        T_cam_table = np.linalg.solve(m.T_world_cam, T_world_table(x[TILT], offset))
        found = self.detector.ball_position(m.ball_px, m.K, T_cam_table[:3, :3], T_cam_table[:3, 3])
        if isinstance(found, str):
            return False
        p = self.params
        x = self.ekf.x.copy()
        x[BALL] = np.concatenate([found[0], np.zeros(4)])
        P = self.ekf.P.copy()
        P[BALL, :] = 0.0
        P[:, BALL] = 0.0
        P[BALL, BALL] = np.diag(
            [p.ball.sigma_v_m**2] * 2 + [p.start_speed_std_mps**2] * 2 + [p.ball.sigma_w**2] * 2
        )
        self.ekf.x, self.ekf.P = x, P
        return True

    # --- output in the env's state layout ---------------------------------------------
    def mean(self) -> np.ndarray:
        x = self.ekf.x
        mean = np.empty(STATE_DIM)
        mean[0:4] = x[0:4]
        mean[4:6] = x[TILT]
        mean[6:8] = self.tilt_model.rate(x[TILT], self.tilt_cmd)
        return mean

    def covariance(self) -> np.ndarray:
        P, g = self.ekf.P, self.tilt_model.rate_gain_per_s
        cov = np.zeros((STATE_DIM, STATE_DIM))
        cov[0:4, 0:4] = P[0:4, 0:4]
        tilt_covariance_blocks(cov, P[TILT, TILT], g)
        # cov(ball, rate) = -g cov(ball, theta): rate = g (u - theta), u known
        cov[0:4, 4:6] = P[0:4, TILT]
        cov[0:4, 6:8] = -g * P[0:4, TILT]
        cov[4:8, 0:4] = cov[0:4, 4:8].T
        return cov


class PixelEKFObserver(FusedObserver):
    """``ekf`` for BallTable-v0: see the module docstring. Fuses each frame at its capture
    time, as ``kf-latency`` does (``latency_aware=False``: when it is delivered, as
    ``kf``).

    Args:
        env: the (unwrapped) env, made with ``obs_mode="rgb"`` or ``"measurements"``.
        params: the filter's parameters.
        detector: the geometry stage, whose ray to the ball's centre places the ball when
            it is first seen or re-acquired (default :class:`BallTableDetector`).
        latency_aware: fuse each frame at its capture time (else at its delivery).
    """

    def __init__(
        self,
        env: BallTableEnv,
        params: PixelEKFParams | None = None,
        detector: BallTableDetector | None = None,
        latency_aware: bool = True,
        r_scale: float = 1.0,
    ) -> None:
        cfg = env.config
        self._env = env
        # In measurements mode kf's measured model error (its Q follows the table's
        # motion from a floor; estimation/ball_table/noise.py, "Q"), as kf has it, unless
        # a calibration error is declared: then the gravity input computed from the tilt
        # carries a constant offset, which kf estimates as states and this EKF leaves to
        # sigma_w (MODEL_ACCEL_STD_MPS2; with the floor instead, at 1 degree of rotation
        # error the ball ended 5.2 mm off, 3.2 mm with sigma_w:
        # tests/estimation/test_ball_table_ekf_calibration.py).
        if cfg.obs_mode == "measurements" and not calibration_variances(env.sensor_spec):
            filters = BallTableObserverParams(
                ball=ball_process_params(cfg, RGB_BALL_STD_M, KF_ACCEL_FLOOR_MPS2),
                measured_model_error=True,
            )
        else:
            filters = BallTableObserverParams(ball=ball_process_params(cfg, RGB_BALL_STD_M))
        self.params = params or PixelEKFParams(filters=filters)
        self.r_scale = checked_r_scale(r_scale)
        filters = self.params.filters
        self.ball_model = RollingBallModel(filters.ball)
        self.tilt_model = TiltLagModel.from_arm(
            cfg.arm_position_gain, cfg.physics_dt_s, filters.tilt_rate_noise_std_radps
        )
        if cfg.obs_mode == "rgb":
            std = dict(RGB_STD_PX)
        else:
            # the declared pixel noise, with the floor for what the model leaves out
            std_px = math.hypot(MEASUREMENT_FLOOR_PX, env.sensor_spec.measurement_noise_std_px)
            std = {RED_TOP: std_px, BORDER_OUTLINE: std_px, "ball": std_px}
        std = {k: v * math.sqrt(self.r_scale) for k, v in std.items()}  # R times r_scale
        given = {
            RED_TOP: self.params.corner_std_px,
            BORDER_OUTLINE: self.params.outline_std_px,
            "ball": self.params.ball_std_px,
        }
        self.pixel_std_px = {k: std[k] if v is None else float(v) for k, v in given.items()}
        self._model_corners = {
            model: model_corners_table(model) for model in (RED_TOP, BORDER_OUTLINE)
        }
        reader = FrameReader(env, detector, type(self).__name__)
        # the calibration's offset on the state, as this model reads a frame
        # (fit_calibration_cov; not in R), reported through the noise rule's ``reported``
        self._calibration_variances = calibration_variances(env.sensor_spec)
        self._last_pixels: PixelMeasurement | None = None
        noise = BallTableNoiseRule(
            env.sensor_spec, cfg.obs_mode == "rgb", reader.detector, (0.0, 0.0), 0.0
        )
        super().__init__(env, reader, latency_aware, noise, self.tilt_model.rate_gain_per_s)

    @property
    def reacquisitions(self) -> int:
        return 0 if self.core is None else self.core.reacquisitions

    def pixel_measurement(
        self, features: BallTableFeatures, K: np.ndarray, T_world_cam: np.ndarray
    ) -> PixelMeasurement:
        """The EKF's measurement from the image stage's features: every corner with a
        finite pixel, and the ball's image when all of it is finite."""
        models = []
        if features.corners_px is not None and features.corner_model is not None:
            models.append((features.corner_model, features.corners_px))
            if features.corner_model == RED_TOP and features.outline_corners_px is not None:
                models.append((BORDER_OUTLINE, features.outline_corners_px))
        points, pixels, std = [np.zeros((0, 3))], [np.zeros((0, 2))], [np.zeros(0)]
        for model, corners_px in models:
            corners_px = np.asarray(corners_px, dtype=float)
            seen = np.all(np.isfinite(corners_px), axis=1)
            points.append(self._model_corners[model][seen])
            pixels.append(corners_px[seen])
            std.append(np.full(int(seen.sum()), self.pixel_std_px[model]))
        ball = features.ball_px
        if ball is not None:
            ball = np.asarray(ball, dtype=float)
            ball = ball if bool(np.all(np.isfinite(ball))) else None
        return PixelMeasurement(
            K,
            T_world_cam,
            np.concatenate(points),
            np.concatenate(pixels),
            np.concatenate(std),
            ball,
            self.pixel_std_px["ball"],
        )

    def reset(self) -> None:
        super().reset()
        self._last_pixels = None

    def _read(self, obs: Any, frame: dict) -> tuple[BallTableFeatures, Fused]:
        features = self.reader.features(obs, frame)
        K, T_world_cam = (np.asarray(frame[k], dtype=float) for k in ("K", "T_world_cam"))
        self._last_pixels = self.pixel_measurement(features, K, T_world_cam)
        return features, Fused(self._last_pixels)

    def _reported(self, covariance: np.ndarray) -> np.ndarray:
        """The core's ``covariance`` plus the calibration's offset as this model reads the
        last frame at the current estimate (:func:`fit_calibration_cov`; the last one
        found while a frame has too few pixels for the fit)."""
        if self._calibration_variances and self._last_pixels is not None:
            sigma = fit_calibration_cov(
                self.core.ekf.x, self._last_pixels, self._calibration_variances
            )
            if sigma is not None:
                self._calibration = sigma
        return super()._reported(covariance)

    def _start(self, time_s: float, measurement: Fused | None) -> tuple[PixelEKF, bool]:
        # the centre's calibration prior at the first frame's nominal camera (without a
        # frame, the env's nominal camera now)
        if measurement is not None:
            K, T_world_cam = measurement.value.K, measurement.value.T_world_cam
        else:
            K, T_world_cam = self._env.camera_intrinsics()[0].K, self._env.camera_pose(0)
        core = PixelEKF(
            self.params.filters,
            self.ball_model,
            self.tilt_model,
            self.reader.detector,
            time_s,
            centre_calibration_cov(self._env.sensor_spec, K, T_world_cam),
            # from rgb the arm's part is left out (see the module docstring)
            np.zeros(3) if self._env.config.obs_mode == "rgb" else TABLE_CENTRE_HOLD_STD_M,
        )
        return core, measurement is not None and core.update(measurement)
