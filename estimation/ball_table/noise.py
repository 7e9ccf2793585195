"""BallTable's noise rule: the measurement noise R of ``kf``/``kf-latency`` (tilt and ball
position on the table, from the geometry stage) and of ``ekf`` (pixels), from what a
calibrated rig knows, the same way under every sensor option. Nothing here is tuned per
condition.

**kf, kf-latency** (the detection: tilt (2,) in rad, ball position on the table (2,) in m):

- ``obs_mode="measurements"``: the declared pixel noise sigma =
  ``SensorSpec.measurement_noise_std_px`` on each of the 11 reported pixels (the red
  top's 4 corners, the ball's centre and radius) through the geometry stage: R = sigma^2
  J J^T, J the stage's Jacobian d(tilt, ball) / d(pixels) at the frame's pixels (central
  differences: the stage is OpenCV's PnP, which gives no derivatives). Seen nearly
  head-on, the red top's square makes the tilt ill-conditioned: 1 px of corner noise is
  about 55 mrad of tilt and 5 mm of ball position (the ball is placed on the estimated
  table). J is kept while every pixel stays within ``JACOBIAN_REUSE_PX`` of where it was
  taken (45 us per geometry-stage call, 22 calls per Jacobian). On perfect pixels the
  stage itself errs a little (:data:`PERFECT_PIXELS_BALL_STD_M`, measured): R gains it;
- ``obs_mode="rgb"``: the detector's error on rendered frames
  (tests/estimation/test_ball_table_detector.py: tilt 3.5 and 1.0 mrad on its two axes,
  ball 0.3 mm; ``BallTableObserverParams.tilt_meas_std_rad`` and ``ball.sigma_v_m``);
- timing, for ``kf`` (which fuses a frame when it is delivered): the frame is older than
  the step it is fused at by its latency a (declared ``latency_s``, spreads
  ``latency_jitter_s`` and ``jitter_s``), and meanwhile the ball moved by v a and the
  tilt by theta' a, so R gains E[a^2] (v v^T + P_v) with E[a^2] = latency_s^2 +
  latency_jitter_s^2 + jitter_s^2 (the same for the tilt with its rate). ``kf-latency``
  fuses at the capture time: no timing term.

**ekf** (pixels): sigma on every pixel in measurements mode; from rgb the image stage's
measured pixel errors (:data:`~observer_gym.estimation.ball_table.pixel_ekf.RGB_STD_PX`).
It fuses at capture time: no timing term.

Every R is the rule's times ``r_scale`` (1; sensitivity studies).

**Calibration**: the declared calibration uncertainty through the geometry stage
(estimation/calibration.py: the stage run with the camera moved along each calibration
parameter) gives the covariance of the offset it puts on the tilt and the ball's
position (and, through the observers' rate g (u - tilt), on the tilt rate). ``kf``'s tilt
filter carries the tilt's offset as states (observer.py, ``TiltBallFilters``), which
move with the scene as the Jacobian does (:meth:`take_offset_change`; re-linearised
every ``CALIBRATION_REUSE_PX``); ``kf`` adds the ball position's offset to the
covariance it reports (:meth:`reported`), not to R (it is the same for every frame of a
calm ball, and the ball filter follows the measured position). The tilt's offset also
offsets the gravity input the ball filter computes from the tilt where the estimate
keeps part of it, an acceleration the real ball does not have: ``kf`` estimates that
offset as two states (observer.py, ``gravity_offset_cov``). ``ekf`` reports the
offset as its own pixel model reads the frame (estimation/ball_table/pixel_ekf.py,
``fit_calibration_cov``, through :meth:`reported`):
it takes the part a translation of the table explains in its state, and under a focal
error settles at another tilt than PnP does.

**Q** (:func:`ball_process_params`, the rolling-ball model's w1 and w2), from the
disturbance model (envs/ball_table/disturbances.py) and what the model leaves out:

- pushes: impulses uniform in [0, ``push_impulse_ns``] in a uniform horizontal direction
  at ``push_rate_hz`` on the ball of mass m, which set its velocity by J / m and roll on
  at 5/7 of that: w1's intensity gains rate (5/7 J / m)^2 / 6 per axis (exact for the
  jumps' variance). A linear filter claims it at every step, where on perfect pixels the
  error is near zero between pushes and far above the claim after one (the ball's
  NEES/dof 0.006-0.04 once calm, 2-16 over the 10 steps after a push), so an episode's
  NEES follows the push energy its seed drew (docs/results/consistency.md, "What moved,
  what it costs": 0.24-0.29 per dof on seeds that drew 31 % of the expected, 0.82-1.02
  on seeds that drew 94 %);
- ``kf``'s model error on the perfect detector's measurements, which follows the
  table's motion (from rendered frames ``kf`` keeps MODEL_ACCEL_STD_MPS2 at every step:
  estimation/ball_table/observer.py says why) (``python
  benchmarks/ball_table_model_error.py [--push-rate-hz 0.5]``: the LQR on the truth, 10
  episodes of 300 steps). The ball's acceleration over a 20 ms step departs from (5/7) g
  sin(tilt) plus the table's angular acceleration h theta'' (RollingBallModel.
  rotation_increment) by 0.076 and 0.018 m/s^2 RMS (x, y) with h the ball's radius; most
  of x's is -17 mm times the tilt_y angular acceleration (the arm's joints lag, so the
  table's centre swings as it turns), which kf's model now has (models.
  KF_ROTATION_HEIGHTS_M): 0.026 and 0.018 m/s^2 RMS left, 0.12 and 0.08 over the first 15
  steps (the swings from a 10 cm start), 0.006 and 0.0005 over steps 15-50, 2e-4 and
  8e-5 after. Each step's error has the std s_i = sqrt(f^2 + (a_i |alpha|)^2 + (b_i
  |theta'|^2)^2) (:func:`motion_accel_var`), alpha and theta' the lag model's angular
  acceleration and mean rate over the step (from the commands, which the filter knows),
  a = (3.5, 2.8) mm and b = (74, 75) mm from a non-negative least-squares fit of e^2 on
  (1, alpha^2, theta'^4). The floor f = ``KF_ACCEL_FLOOR_MPS2`` = 0.006 m/s^2 is the
  error's RMS on x over steps 15-50 (0.0056), while the table settles, which the motion
  terms claim 4x too little of; with the calm error as its floor (3e-4) kf from rendered
  frames read NEES/dof 39 (34-51; tests/estimation/test_consistency_ball_table.py::
  test_from_rendered_frames_at_the_defaults): the rgb detector's error persists from
  frame to frame while the ball is still, and R, white, lets a filter that trusts its
  model average it away. With the calm floor the model claims the error as a whole
  (mean(e^2) / mean(s^2): 1.3 and 0.8), but not window by window: 1.3 and 0.8 in the
  first 15 steps, 3.9 and 0.05 in steps 15-50, 0.5 and 0.06 after (with f: 1.3 and 0.8,
  0.7 and 0.01, under 0.01 after; 1.2 and 0.7 as a whole). The error is no white noise
  whose variance the instantaneous alpha and theta' set: on x, e / s has a lag-one
  correlation of 0.70 over the first 15 steps and 0.95 over steps 15-50 (a slowly
  varying bias, which no per-step fit, least squares or maximum likelihood, can
  calibrate). So kf claims s twice: as it comes, a white acceleration held over the step
  (observer.py, ``TiltBallFilters._settle``), and as it persists, driving w2 (stationary
  std s, correlation time 1 / beta = 0.2 s; f is w2's stationary std and w1's intensity
  f^2 x 20 ms). With the white part alone (and the calm floor) kf restarted its ball
  filter 5 times in 8 episodes at the defaults (no pushes, 0 px; steps 3-41, good frames
  gated), with both 0 times. Before (``ekf``'s still): sigma_w =
  ``MODEL_ACCEL_STD_MPS2`` = 0.5 m/s^2 at every step, sized for the swings and single
  pushes, which claimed ~50x the error once the table was calm (kf's NEES/dof 0.10 at 0
  px). A push is now one jump well outside the prediction at 0 px: the gate rejects it
  and the filter restarts from the rejected measurements (observer.py): 1-2 restarts per
  episode at 0 px with pushes at 0.5 Hz (0 before), which raise the ball's position
  error; at 0.5 px the position and velocity errors fall (``observer-gym run --env
  BallTable-v0 --observer kf-measurements --controller lqr --episodes 5 --steps 300
  --workers 1 --env-option push_rate_hz=0.5 --env-option measurement_noise_px=0``, and
  ``=0.5``: position RMSE 0.086 -> 0.156 mm and 2.08 -> 1.51 mm, velocity 4.7 -> 5.5
  and 31.2 -> 12.3 mm/s). At the defaults (no pushes, 0 px; ``observer-gym run --env
  BallTable-v0 --observer kf-measurements --controller lqr --episodes 20 --workers 1``)
  kf's NEES/dof is 0.16 (0.07 before): once calm, f claims the settling error.

The tilt rate's departure from the lag model (observer.py, ``rate_model_var``) is
quadratic in the rate and its reported variance follows it; a delivery-time ``kf``
reports what the ball did over its frames' age (observer.py,
``TiltBallFilters._add_frame_age``).
"""

from __future__ import annotations

import math

import numpy as np

from observer_gym.envs.sensor import SensorSpec
from observer_gym.estimation.ball_table.features import RED_TOP, BallTableFeatures
from observer_gym.estimation.ball_table.geometry_stage import BallTableDetector
from observer_gym.estimation.ball_table.models import ROLLING_ACCEL_FACTOR, RollingBallParams
from observer_gym.estimation.calibration import calibration_jacobian, calibration_variances
from observer_gym.estimation.r_scale import checked_r_scale

__all__ = [
    "JACOBIAN_REUSE_PX",
    "PERFECT_PIXELS_BALL_STD_M",
    "PERFECT_PIXELS_TILT_STD_RAD",
    "BallTableNoiseRule",
    "ball_process_params",
]

# The geometry stage's own error on the perfect detector's pixels (measurements mode at
# 0 px), what the model leaves out (the ball's contact with the table; float32 pixels):
# measured RMS 0.015 and 0.007 mm of ball position, 0.00016 mrad of tilt, over 6
# episodes of the LQR with pushes (tests/estimation/test_consistency_ball_table.py::
# test_the_model_floors_cover_the_sim); the ball's taken larger for its tails (0.26 mm
# at most).
PERFECT_PIXELS_BALL_STD_M = 3e-5
PERFECT_PIXELS_TILT_STD_RAD = 2e-7
JACOBIAN_REUSE_PX = 2.0
# The calibration's Jacobian is re-linearised when a pixel moved more than this: kf's
# tilt offset moves with it, and at 2 px the steps it takes lagged the offset's motion
# (kf's NEES/dof 6.3 on one of 3 episodes at 1 degree of rotation error; 0.6 at 0.5 px)
CALIBRATION_REUSE_PX = 0.5
# ekf's rolling model's acceleration error (see the module docstring), over MODEL_STEP_S:
# its 99th percentile before the model had the table's angular acceleration, kept as the
# margin that also covers single pushes.
MODEL_ACCEL_STD_MPS2 = 0.5
MODEL_STEP_S = 0.02
# kf's rolling model's acceleration error (x, y) as it follows the table's motion (see the
# module docstring): its floor (m/s^2, the error's RMS on x while the table settles), and
# per axis a term per rad/s^2 of the angular acceleration and one per (rad/s)^2 of the
# squared tilt rate (each m).
KF_ACCEL_FLOOR_MPS2 = 0.006
MOTION_ALPHA_COEF_M = (0.0035, 0.0028)
MOTION_RATE_SQ_COEF_M = (0.074, 0.075)
BALL_MASS_KG = (
    0.05  # envs/assets/ball.urdf  # a Jacobian serves while no pixel moved more than this
)
_STEP_PX = 0.01  # central-difference step


def ball_process_params(
    config, sigma_v_m: float, accel_std_mps2: float | None = None
) -> RollingBallParams:
    """The rolling-ball model's noise for a BallTable config (see the module docstring),
    with ``sigma_v_m`` as its position noise (the rgb detector's) and ``accel_std_mps2``
    as the model's acceleration error (None: MODEL_ACCEL_STD_MPS2)."""
    sigma_w = MODEL_ACCEL_STD_MPS2 if accel_std_mps2 is None else accel_std_mps2
    # w1's intensity: sigma_w^2 dt (the model's error) + rate (5/7 J / m)^2 / 6 (pushes)
    push_dv_mps = ROLLING_ACCEL_FACTOR * config.push_impulse_ns / BALL_MASS_KG
    q_w1 = sigma_w**2 * MODEL_STEP_S + config.push_rate_hz * push_dv_mps**2 / 6.0
    return RollingBallParams(
        sigma_w=sigma_w,
        sigma_v_m=sigma_v_m,
        w1_psd_time_s=q_w1 / sigma_w**2,
    )


def motion_accel_var(angular_accel_radps2: np.ndarray, rate_radps: np.ndarray) -> np.ndarray:
    """The variance (2,) in (m/s^2)^2 of ``kf``'s rolling model's acceleration error on
    (x, y) over a step beyond its floor, from the table's motion over it: the lag
    model's angular acceleration alpha and mean rate theta' (rad/s^2, rad/s; (tilt_x,
    tilt_y) each)."""
    alpha_sq = float(np.sum(np.square(angular_accel_radps2)))
    rate_sq = float(np.sum(np.square(rate_radps)))
    # s_i^2 = (a_i |alpha|)^2 + (b_i |theta'|^2)^2
    a, b = np.asarray(MOTION_ALPHA_COEF_M), np.asarray(MOTION_RATE_SQ_COEF_M)
    return a**2 * alpha_sq + (b * rate_sq) ** 2


def _readonly(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


class BallTableNoiseRule:
    """R of BallTable's filters for one env (see the module docstring).

    Args:
        sensor: the declared sensor (``env.sensor_spec``).
        from_pixels: the env renders frames (``obs_mode="rgb"``).
        detector: the geometry stage the detections come from.
        rgb_tilt_std_rad, rgb_ball_std_m: the rgb detector's measured errors.
        r_scale: R as the rule gives it times this (> 0).
        fused_at_delivery: the filter fuses a frame at the step it is delivered in (adds
            the timing term).
    """

    def __init__(
        self,
        sensor: SensorSpec,
        from_pixels: bool,
        detector: BallTableDetector,
        rgb_tilt_std_rad: tuple[float, float],
        rgb_ball_std_m: float,
        r_scale: float = 1.0,
        fused_at_delivery: bool = False,
    ) -> None:
        self.sensor = sensor
        self.r_scale = checked_r_scale(r_scale)
        self.from_pixels = bool(from_pixels)
        self.detector = detector
        self.pixel_var_px2 = sensor.measurement_noise_std_px**2
        # E[a^2] of a frame's age at the step it is fused at (0 for capture-time fusion)
        self.age_sq_s2 = (
            sensor.latency_s**2 + sensor.latency_jitter_s**2 + sensor.jitter_s**2
            if fused_at_delivery
            else 0.0
        )
        s = self.r_scale
        self._rgb_R = (
            _readonly(s * np.diag(np.square(np.asarray(rgb_tilt_std_rad, dtype=float)))),
            _readonly(s * rgb_ball_std_m**2 * np.eye(2)),
        )
        self._linearised: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._calibration_variances = calibration_variances(sensor)
        # the declared calibration's covariance of (tilt, ball), the pixels it was taken
        # at and its Jacobian in the calibration's parameters
        self._calibrated: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        # the covariance (4, 4) of the offset's change since take_offset_change
        self._offset_change: np.ndarray | None = None

    def reset(self) -> None:
        self._linearised = None
        self._calibrated = None
        self._offset_change = None

    @property
    def declares_calibration(self) -> bool:
        """The sensor declares a calibration error (some calibration variance > 0)."""
        return bool(self._calibration_variances)

    # --- the calibration's offset (reported, not in R) ---------------------------------
    def calibration_cov(
        self, features: BallTableFeatures, K: np.ndarray, T_world_cam: np.ndarray
    ) -> np.ndarray | None:
        """The declared calibration uncertainty's covariance (4, 4) of (tilt, ball position)
        at these features (estimation/calibration.py), None without calibration error
        or a table and ball; kept while no pixel moves more than ``CALIBRATION_REUSE_PX``."""
        if not self._calibration_variances:
            return None
        pixels = _measured_pixels(features)
        if pixels is None or pixels.size != 11:
            return None if self._calibrated is None else self._calibrated[1]
        cached = self._calibrated
        if (
            cached is not None
            and cached[0].size == pixels.size
            and np.all(np.abs(pixels - cached[0]) <= CALIBRATION_REUSE_PX)
        ):
            return cached[1]

        def detected(K_: np.ndarray, T_: np.ndarray) -> np.ndarray | None:
            detection = self.detector.detect(features, K_, T_)
            if not (detection.table_found and detection.ball_found):
                return None
            return np.concatenate([detection.tilt_rad, detection.ball_pos_table_m])

        jacobian = calibration_jacobian(detected, K, T_world_cam, self._calibration_variances)
        if jacobian is None:
            return None if cached is None else cached[1]
        J, var = jacobian
        # Sigma = J diag(var) J^T
        sigma = (J * var).dot(J.T)
        sigma = 0.5 * (sigma + sigma.T)
        if cached is not None:
            # the offset d = J c moved with the scene: d_new - d_old = (J_new - J_old) c
            dJ = J - cached[2]
            change = (dJ * var).dot(dJ.T)
            change = 0.5 * (change + change.T)
            self._offset_change = (
                change if self._offset_change is None else self._offset_change + change
            )
        self._calibrated = (pixels, sigma, J)
        return sigma

    def take_offset_change(self) -> np.ndarray | None:
        """The covariance (4, 4) of how far the calibration's offset of (tilt, ball) moved
        since the last call (None: it was not re-linearised since): the offset is J c for
        the fixed calibration error c, and J follows the scene, so each new Jacobian moves
        it by (J_new - J_old) c, of covariance dJ diag(var) dJ^T."""
        change, self._offset_change = self._offset_change, None
        return change

    def reported(
        self,
        cov: np.ndarray,
        calibration: np.ndarray | None,
        rate_gain_per_s: float,
        tilt_estimated: bool = False,
    ) -> np.ndarray:
        """The covariance an observer reports (the env's state layout, a new array): its
        filters' ``cov`` plus the calibration's offset d = (d_tilt, d_ball), which the
        filters do not hold, on the ball's position (0:2), the tilt (4:6) and the tilt
        rate (6:8), which the observers compute as g (u - tilt): an offset d_tilt on the
        tilt is -g d_tilt on the rate. Added: A Sigma A^T with the rows of A mapping d
        to those entries. ``tilt_estimated``: the filters carry d_tilt as states (``kf``'s
        tilt filter), so their ``cov`` holds the tilt's share; only d_ball is added."""
        if calibration is None:
            return cov
        A = np.zeros((cov.shape[0], 4))
        if not tilt_estimated:
            A[4:6, 0:2] = np.eye(2)  # tilt += d_tilt
            A[6:8, 0:2] = -rate_gain_per_s * np.eye(2)  # rate += -g d_tilt
        A[0:2, 2:4] = np.eye(2)  # ball position += d_ball
        out = np.array(cov, dtype=float) + A.dot(calibration).dot(A.T)
        out.flags.writeable = False
        return out

    # --- kf: tilt and ball -------------------------------------------------------------
    def detection_R(
        self, features: BallTableFeatures, K: np.ndarray, T_world_cam: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(R of the tilt (2, 2), R of the ball's position (2, 2)) of a detection from
        ``features``, before the timing term; read-only arrays, the same objects while
        the Jacobian is reused."""
        if self.from_pixels:
            return self._rgb_R
        pixels = _measured_pixels(features)
        cached = self._linearised
        if pixels is None:  # no table: nothing to weigh
            return self._rgb_R
        if (
            cached is not None
            and cached[0].size == pixels.size
            and np.all(np.abs(pixels - cached[0]) <= JACOBIAN_REUSE_PX)
        ):
            return cached[1], cached[2]
        J = self._jacobian(pixels, K, T_world_cam)
        if J is None:  # the stage fails beside these pixels: keep the last R
            return (cached[1], cached[2]) if cached is not None else self._rgb_R
        # R = sigma^2 J J^T + the stage's own error on perfect pixels, tilt's and ball's
        R = self.pixel_var_px2 * J.dot(J.T)
        R[:2, :2] += PERFECT_PIXELS_TILT_STD_RAD**2 * np.eye(2)
        if R.shape[0] == 4:
            R[2:, 2:] += PERFECT_PIXELS_BALL_STD_M**2 * np.eye(2)
        R *= self.r_scale
        R_tilt = _readonly(R[:2, :2].copy())
        R_ball = _readonly(R[2:, 2:].copy()) if R.shape[0] == 4 else self._rgb_R[1]
        self._linearised = (pixels, R_tilt, R_ball)
        return R_tilt, R_ball

    def _jacobian(self, pixels: np.ndarray, K, T_world_cam) -> np.ndarray | None:
        """d(tilt, ball) / d(pixels) (4, 11), or d(tilt) / d(corners) (2, 8) without a
        ball, by central differences; None if the stage finds no table (or ball) beside
        ``pixels``."""
        columns = []
        for i in range(pixels.size):
            step = np.zeros(pixels.size)
            step[i] = _STEP_PX
            ahead = self._detected(pixels + step, K, T_world_cam)
            behind = self._detected(pixels - step, K, T_world_cam)
            if ahead is None or behind is None:
                return None
            columns.append((ahead - behind) / (2.0 * _STEP_PX))
        return np.column_stack(columns)

    def _detected(self, pixels: np.ndarray, K, T_world_cam) -> np.ndarray | None:
        with_ball = pixels.size == 11
        ball_px = pixels[8:11] if with_ball else None
        features = BallTableFeatures(
            pixels[:8].reshape(4, 2), ball_px, RED_TOP, source="measurement"
        )
        detection = self.detector.detect(features, K, T_world_cam)
        if not detection.table_found or (with_ball and not detection.ball_found):
            return None
        if not with_ball:
            return np.asarray(detection.tilt_rad, dtype=float)
        return np.concatenate([detection.tilt_rad, detection.ball_pos_table_m])

    def with_timing(self, R: np.ndarray, rate: np.ndarray, rate_cov: np.ndarray) -> np.ndarray:
        """R plus the timing term of a delivery-time filter, r_scale E[a^2] (v v^T + P_v),
        for the measured quantity's rate v and its covariance (R itself without one)."""
        if self.age_sq_s2 == 0.0:
            return R
        v = np.asarray(rate, dtype=float)
        return R + self.r_scale * self.age_sq_s2 * (np.outer(v, v) + rate_cov)

    # --- ekf: pixels -------------------------------------------------------------------
    def pixel_std_px(self, rgb_std_px: float) -> float:
        """The std of one pixel for ``ekf`` (before ``r_scale``): the declared noise in
        measurements mode, ``rgb_std_px`` (the image stage's measured error) from rgb."""
        return rgb_std_px if self.from_pixels else math.sqrt(self.pixel_var_px2)


def _measured_pixels(features: BallTableFeatures) -> np.ndarray | None:
    """The pixels of a measurement's red-top corners (8) and ball (3) if it was seen with
    finite pixels; None without a table with finite corners."""
    if features.corners_px is None or features.corner_model != RED_TOP:
        return None
    corners = np.asarray(features.corners_px, float).ravel()
    if not np.all(np.isfinite(corners)):
        return None
    ball = None if features.ball_px is None else np.asarray(features.ball_px, float)[:3]
    if ball is None or not np.all(np.isfinite(ball)):  # no ball detection: the tilt's alone
        return corners
    return np.concatenate([corners, ball])
