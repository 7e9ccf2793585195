"""TargetFollower's noise rule: the measurement noise R and the process noise Q of its
filters (the VSE ``kf``/``stkf``, their latency-aware drive and the pixel ``ekf``) from
what a calibrated rig knows, the same way under every sensor option. Nothing here is
tuned per condition.

**R** (px^2; the detection (x_i, y_i, d_x)), times ``r_scale`` (1; sensitivity studies):

- ``obs_mode="measurements"``: the declared pixel noise,
  ``SensorSpec.measurement_noise_std_px``^2 on each entry (the env's model Z = round(X +
  sigma_n (2 w - 1)): sigma_n^2 / 3 + 1/12 px^2);
- ``obs_mode="rgb"``: the detector's error model at the declared ``image_noise_std``
  (:mod:`~observer_gym.estimation.target_follower.detector_error`, measured on rendered
  frames): its scatter about its mean, s_j^2 = (rms_j^2 - mean_j^2) d_x^2. Its mean
  b_j = mean_j d_x (the blob's rim lost to image noise: d_x -9 % at 32) stays while the
  target is held and no innovation sees it: b_j^2 is added to the reported variance of
  the estimate, as the principal-point offset is (below);
- timing, for the filter that fuses a frame when it is delivered (``kf``/``stkf``): the
  frame is older than the step time it is fused at by its latency a (declared mean
  ``latency_s``, spreads ``latency_jitter_s`` and ``jitter_s``), and meanwhile the image
  moved at v = X_i^t' + B_i u, so R gains E[a^2] (v v^T + P_rate) with
  E[a^2] = latency_s^2 + latency_jitter_s^2 + jitter_s^2. Its estimate is the image of
  its frames' capture, a before the step it reports at, so the reported covariance gains
  the same term (:meth:`NoiseRule.reported`): without it ``kf`` read NEES/dof 2.9 at
  0.03 s and 2.5 at 0.15 s (6.98 at a higher latency on other seeds), with it 1.7 and 1.2
  (tests/estimation/test_consistency_latency.py). The capture-time filters use the
  reported capture time: no timing term.

**Calibration** (the declared sizes; a size s in a uniform direction is a random variable
of that size): in this env the truth is what the real camera sees and the perfect
detector reports the real camera's image state, so a calibration error does not move a
measurement against the truth. It enters where it acts:

- the robot's own image motion T B_i u is computed with the nominal f_x, f_y and the
  nominal tilt: the focal error (relative size e_f, sign unknown: variance e_f^2) scales
  it, the rotation error (s rad) turns it by up to s; Q's image block gains
  (e_f^2 + s^2) (T B_i u)(T B_i u)^T (s^2 for every direction: an upper bound);
- the principal point error (p px) offsets an rgb detection (the detector subtracts the
  nominal c_x, c_y) by p in a uniform direction, variance p^2 / 2 per axis. It is a
  constant offset, which no innovation sees: it is added to the reported covariance of
  (x_i, y_i), not to R.

**Rounding** (measurements): the env rounds each entry to a whole pixel, the part of the
declared variance beyond the uniform noise's sigma_n^2 / 3 (1/12 px^2). While the image
moves less than a pixel per frame (a slow or still target held centred) that error stays
the same from frame to frame, and the filter, which takes R as white, would average it
below what it is. The reported variance of each of (x_i, y_i, d_x) is therefore at least
the rounding's (:meth:`NoiseRule.reported`); the filter's own P is not changed.

**Q**, from the disturbance model (:mod:`~observer_gym.envs.target_follower.motion`, the
env config's world options): the target's velocity per world axis is modelled as a
first-order Gauss-Markov process of the motion's stationary variance sigma_v^2 and time
scale tau_v, whose increments over horizons below tau_v are those of a white acceleration
of intensity q = 2 sigma_v^2 / tau_v ((m/s^2)^2 s):

- ``random_walk``: the Ornstein-Uhlenbeck drive (std s_w = ``walk_speed_mps``, tau = 2 s)
  through the lag tau_l = 0.5 s has sigma_v^2 = s_w^2 tau / (tau + tau_l) and time scale
  tau_v = tau + tau_l (horizontal; the height's drive, std 0.05 m/s, is smaller); over a
  step the white model overstates the lagged walk's velocity change (it is smooth), over
  the 1-3 s of an occlusion it matches it;
- ``profile`` (44): sigma_v^2 = (0.15 m/s)^2 / 4 per horizontal axis, tau_v = 1 / turn
  rate (the velocity's direction turns at it; pi / 20 when it does not turn);
- ``static``: none;
- pushes: jumps of uniform size in [0, ``push_speed_mps``] in a uniform horizontal
  direction at ``push_rate_hz``: q += rate push^2 / 6 per axis (exact for the jumps),
  sigma_v^2 += rate push^2 tau_d / 12 (their decay, tau_d = 1 s).

The filters take q and sigma_v^2 isotropic, the largest axis's on every axis: they map
world directions into image rates through the estimated state, so an axis without noise
(the profile's vertical) would become an image direction the filter claims to know
exactly, which it does not (measured: median episode NEES/dof 1.35 (kf) and 3.1 (ekf)
with the profile's zero vertical noise, 0.51 and 0.49 isotropic).

The pixel EKF integrates q over each interval in world axes, Q = q [[dt^3/3, dt^2/2],
[dt^2/2, dt]] per axis. The VSE's state is the image state and its target-induced rate:
an acceleration a_c of the target (camera axes) changes that rate by J a_c with

    J = [[k_x, 0, -x_i / z], [0, -k_y, -y_i / z], [0, 0, -d_x / z]],
    k_x = d_x / W,  k_y = f_y d_x / (f_x W),  1 / z = d_x / (f_x W)

(the image rate's derivative in the target's velocity at the current estimate: its depth
is read from d_x), so Q = [[dt^3/3, dt^2/2], [dt^2/2, dt]] (x) q J J^T. The camera's own
rotation omega_c (yaw rate, tilt rate; camera axes at the tilt) turns the target's
velocity in camera axes, V_c' = -omega_c x V_c, which (30) does not model: Q gains
G (sigma_v^2 J [omega_c]x [omega_c]x^T J^T) G^T, G = [dt^2/2, dt]. A (re)started track's
rates get the prior sigma_v^2 J J^T.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from observer_gym.envs.sensor import SensorSpec
from observer_gym.envs.target_follower.motion import (
    HEIGHT_SPEED_STD_MPS,
    PROFILE_SPEED_MPS,
    PUSH_DECAY_S,
    WALK_LAG_S,
    WALK_TIME_CONSTANT_S,
)
from observer_gym.estimation.r_scale import checked_r_scale
from observer_gym.estimation.target_follower.detector_error import (
    DetectorErrorModel,
    load_detector_error,
)

__all__ = ["NoiseRule", "TargetMotionNoise", "target_motion_noise"]


@dataclass(frozen=True)
class TargetMotionNoise:
    """The target's motion as white acceleration noise, the same on every axis (see the
    module docstring)."""

    accel_psd: float  # q, (m/s^2)^2 s
    velocity_var: float  # sigma_v^2, (m/s)^2, the stationary velocity variance


def target_motion_noise(config) -> TargetMotionNoise:
    """q and sigma_v^2 of a TargetFollower config's target motion and pushes, the largest
    axis's (see the module docstring)."""
    var_h = var_v = q_h = q_v = 0.0
    if config.target_motion == "random_walk":
        tau, lag = WALK_TIME_CONSTANT_S, WALK_LAG_S
        # sigma_v^2 = s^2 tau / (tau + tau_l), q = 2 sigma_v^2 / (tau + tau_l)
        var_h = config.walk_speed_mps**2 * tau / (tau + lag)
        var_v = HEIGHT_SPEED_STD_MPS**2 * tau / (tau + lag)
        q_h, q_v = 2.0 * var_h / (tau + lag), 2.0 * var_v / (tau + lag)
    elif config.target_motion == "profile":
        var_h = PROFILE_SPEED_MPS**2 / 4.0  # v_t^2 cos^2 averaged, half per axis
        turn_radps = max(abs(config.profile_turn_rate_radps), math.pi / 20.0)
        q_h = 2.0 * var_h * turn_radps  # q = 2 sigma_v^2 / tau_v, tau_v = 1 / turn rate
    # pushes: q += rate push^2 / 6, sigma_v^2 += rate push^2 tau_d / 12 (per axis)
    push_sq = config.push_rate_hz * config.push_speed_mps**2
    q_h += push_sq / 6.0
    var_h += push_sq * PUSH_DECAY_S / 12.0
    return TargetMotionNoise(max(q_h, q_v), max(var_h, var_v))


def _blocks(a: float, b: float, c: float, M: np.ndarray) -> np.ndarray:
    """[[a, b], [b, c]] (x) M for a 3 x 3 M (np.kron's result, without its overhead)."""
    out = np.empty((6, 6))
    out[:3, :3] = a * M
    out[:3, 3:] = out[3:, :3] = b * M
    out[3:, 3:] = c * M
    return out


def _cross(w: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


class NoiseRule:
    """R, Q and the start prior of TargetFollower's filters for one env (see the module
    docstring).

    Args:
        sensor: the declared sensor (``env.sensor_spec``).
        config: the env's config (its world options: the target motion and pushes; its
            obs_mode).
        calibration: the nominal calibration (``env.calibration``: f_x, f_y, W).
        r_scale: R as the rule gives it times this (> 0).
        fused_at_delivery: the filter fuses a frame at the step it is delivered in (adds
            the timing term to R).
        detector_error: the rgb detector's model (default: the stored one).
    """

    def __init__(
        self,
        sensor: SensorSpec,
        config,
        calibration: dict,
        r_scale: float = 1.0,
        fused_at_delivery: bool = False,
        detector_error: DetectorErrorModel | None = None,
    ) -> None:
        self.sensor = sensor
        self.r_scale = checked_r_scale(r_scale)
        self.from_pixels = config.obs_mode == "rgb"
        self.fx_px = float(calibration["fx_px"])
        self.fy_px = float(calibration["fy_px"])
        self.width_m = float(calibration["target_width_m"])
        self.motion = target_motion_noise(config)
        if self.from_pixels:
            detector_error = detector_error or load_detector_error()
            self._relative_scatter = detector_error.relative_scatter(sensor.image_noise_std)
            self._relative_bias = detector_error.relative_bias(sensor.image_noise_std)
        self._pixel_var_px2 = sensor.measurement_noise_std_px**2
        # E[a^2] of a frame's age at the step it is fused at (0 for capture-time fusion)
        self.age_sq_s2 = (
            sensor.latency_s**2 + sensor.latency_jitter_s**2 + sensor.jitter_s**2
            if fused_at_delivery
            else 0.0
        )
        # relative error of the robot's image motion: focal (e_f^2) and rotation (s^2)
        self.robot_motion_rel_var = (
            sensor.calib_focal_error**2 + math.radians(sensor.calib_rotation_error_deg) ** 2
        )
        pp_var = 0.5 * sensor.calib_principal_point_error_px**2 if self.from_pixels else 0.0
        self.image_bias_cov = np.diag([pp_var, pp_var, 0.0])
        # the rounding's share of the declared variance: std^2 - sigma_n^2 / 3
        self.rounding_var_px2 = (
            0.0
            if self.from_pixels
            else max(self._pixel_var_px2 - sensor.measurement_noise_px**2 / 3.0, 0.0)
        )

    @classmethod
    def for_env(cls, env, r_scale: float = 1.0, fused_at_delivery: bool = False) -> NoiseRule:
        """The rule for a TargetFollower env (its ``sensor_spec``, config, calibration)."""
        return cls(env.sensor_spec, env.config, env.calibration, r_scale, fused_at_delivery)

    # --- R ------------------------------------------------------------------------------
    def detection_var_px2(self, width_px: float) -> np.ndarray:
        """The detection's variance per entry (3,), before ``r_scale`` and timing."""
        if self.from_pixels:
            # s_j^2 = (rms_j^2 - mean_j^2) d_x^2 (the detector's scatter about its mean)
            return (self._relative_scatter * max(float(width_px), 0.0)) ** 2
        # the declared pixel noise on every entry
        return np.full(3, self._pixel_var_px2)

    def R(
        self,
        z_px: np.ndarray,
        image_rate_pxps: np.ndarray | None = None,
        rate_cov: np.ndarray | None = None,
    ) -> np.ndarray:
        """R (3, 3) of the detection ``z_px``; with the total image rate v (3,) and the
        estimate's rate covariance, the timing term E[a^2] (v v^T + P_rate) of a
        delivery-time filter."""
        R = np.diag(self.detection_var_px2(z_px[2]))
        if image_rate_pxps is not None:
            rate_cov = np.zeros((3, 3)) if rate_cov is None else rate_cov
            R = R + self.frame_age_cov(image_rate_pxps, rate_cov)
        return self.r_scale * R

    def frame_age_cov(self, image_rate_pxps: np.ndarray, rate_cov: np.ndarray) -> np.ndarray:
        """What the image did over a delivery-time filter's frame age (3, 3; px^2):
        E[a^2] (v v^T + P_rate) for the total image rate v and the estimate's rate
        covariance (zeros for a capture-time filter)."""
        if self.age_sq_s2 == 0.0:
            return np.zeros((3, 3))
        v = np.asarray(image_rate_pxps, dtype=float)
        return self.age_sq_s2 * (np.outer(v, v) + np.asarray(rate_cov, dtype=float))

    def reported(
        self, P: np.ndarray, X_i: np.ndarray, image_rate_pxps: np.ndarray | None = None
    ) -> np.ndarray:
        """The covariance an observer reports for its (X_i, X_i^t') estimate with filter
        covariance ``P`` (6, 6): plus the principal-point offset on (x_i, y_i) and (rgb)
        the detector's bias b_j^2 at the estimated width, and each of (x_i, y_i, d_x) at
        least the rounding's variance (a new array). Given the total image rate v (3,), a
        delivery-time filter's estimate, which is the image of its frames' capture, a
        (the frame's age) before the step, also gains what the image did over a,
        :meth:`frame_age_cov` (the same term its R has)."""
        P = np.array(P, dtype=float)
        if image_rate_pxps is not None:
            P[:3, :3] += self.frame_age_cov(image_rate_pxps, P[3:, 3:])
        P[:3, :3] += self.image_bias_cov
        if self.from_pixels:
            # b_j^2 = (mean_j d_x)^2
            P[:3, :3] += np.diag((self._relative_bias * max(float(X_i[2]), 0.0)) ** 2)
        for j in range(3):
            P[j, j] = max(P[j, j], self.rounding_var_px2)
        return P

    # --- Q and the prior, image state (the VSE) ----------------------------------------
    def image_jacobian(self, X_i: np.ndarray) -> np.ndarray:
        """J (3, 3): d X_i^t' / d V_c at the image state X_i (see the module docstring)."""
        x_i, y_i, d_x = (float(v) for v in X_i[:3])
        d_x = max(d_x, 1e-6)
        inv_z = d_x / (self.fx_px * self.width_m)  # 1 / z = d_x / (f_x W)
        k_x = d_x / self.width_m
        k_y = self.fy_px * inv_z
        return np.array(
            [[k_x, 0.0, -x_i * inv_z], [0.0, -k_y, -y_i * inv_z], [0.0, 0.0, -d_x * inv_z]]
        )

    def rate_prior(self, X_i: np.ndarray) -> np.ndarray:
        """sigma_v^2 J J^T (3, 3): the target-induced rate's stationary covariance."""
        J = self.image_jacobian(X_i)
        return self.motion.velocity_var * J.dot(J.T)

    def image_Q(
        self,
        X_i: np.ndarray,
        tilt_rad: float,
        dt_s: float,
        applied: np.ndarray,
        robot_image_rate_pxps: np.ndarray,
    ) -> np.ndarray:
        """Q (6, 6) of (30) over ``dt_s`` at the image state X_i and tilt, the robot's
        velocity ``applied`` (v, omega, omega_t) and its image rate B_i u."""
        J = self.image_jacobian(X_i)
        dt = float(dt_s)
        # [[dt^3/3, dt^2/2], [dt^2/2, dt]] (x) q J J^T
        M = self.motion.accel_psd * J.dot(J.T)
        Q = _blocks(dt**3 / 3.0, dt**2 / 2.0, dt, M)
        # the camera's rotation turning V_c, omega_c = omega_t e_x + omega (world up in
        # camera axes: (0, -cos(phi), sin(phi)) for OpenCV's y down, z forward)
        omega, omega_t = float(applied[1]), float(applied[2])
        if (omega != 0.0 or omega_t != 0.0) and self.motion.velocity_var > 0.0:
            c, s = math.cos(tilt_rad), math.sin(tilt_rad)
            A = J.dot(_cross(np.array([omega_t, -omega * c, omega * s])))  # J [w_c]x
            M_rot = self.motion.velocity_var * A.dot(A.T)
            Q += _blocks(dt**4 / 4.0, dt**3 / 2.0, dt**2, M_rot)
        # calibration: (e_f^2 + s^2) (T B_i u)(T B_i u)^T on the image state
        if self.robot_motion_rel_var > 0.0:
            b = dt * np.asarray(robot_image_rate_pxps, dtype=float)
            Q[:3, :3] += self.robot_motion_rel_var * np.outer(b, b)
        return Q

    def image_P0(self, z_px: np.ndarray, tilt_rad: float) -> np.ndarray:
        """P_0 (6, 6) of a track started at the detection ``z_px``: R and the rate prior."""
        P0 = np.zeros((6, 6))
        P0[:3, :3] = self.R(z_px)
        P0[3:, 3:] = self.rate_prior(z_px)
        return 0.5 * (P0 + P0.T)

    # --- Q and the prior, world (the pixel EKF) -----------------------------------------
    def world_Q(self, dt_s: float) -> np.ndarray:
        """Q (6, 6) of the constant-velocity world model over ``dt_s``."""
        dt = float(dt_s)
        return _blocks(dt**3 / 3.0, dt**2 / 2.0, dt, self.motion.accel_psd * np.eye(3))

    @property
    def world_velocity_prior(self) -> np.ndarray:
        """sigma_v^2 I (3, 3): a (re)started EKF's velocity covariance."""
        return self.motion.velocity_var * np.eye(3)
