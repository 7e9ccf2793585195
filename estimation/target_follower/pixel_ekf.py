"""``ekf``: an extended Kalman filter on the target's world position and velocity, updated
straight from the detection (x_i, y_i, d_x) through the pinhole camera, fused at each
frame's capture time.

State x = (p_w, v_w) (m, m/s; world frame), the target moving at a nearly constant
velocity (white acceleration noise of intensity q):

    x(t + dt) = F x(t),  F = [[I, dt I], [0, I]],
    Q = q [[dt^3/3 I, dt^2/2 I], [dt^2/2 I, dt I]].

Measurement: the detection of a frame captured at t with the nominal camera pose
``T_world_cam`` of that frame (its ``info["frames"][i]``: the robot's odometry and tilt
encoder, so the robot's own motion needs no model here) and the nominal intrinsics,

    z = h(p_w; T_world_cam) + e,  h = (f_x X / Z, -f_y Y / Z, f_x W / Z),  E[e e^T] = R,

(p_c = (X, Y, Z) the target in the camera frame, W its known width;
:mod:`~observer_gym.estimation.target_follower.target_projection`), linearised at the
prediction with the analytic Jacobian (:class:`~observer_gym.estimation.ekf.
ExtendedKalmanFilter`). Each frame is fused at its capture time and the estimate predicted
to the step's time by :class:`~observer_gym.estimation.latency.CaptureTimeFusion`.

Noise: the noise rule (:mod:`~observer_gym.estimation.target_follower.noise`): R from
the declared sensor (times ``r_scale``), the white acceleration q of the target's motion
model per world axis, Q = q [[dt^3/3, dt^2/2], [dt^2/2, dt]]. A track starts at a
detection: p_w by the pinhole model inverted (Z = f_x W / d_x) with covariance G R G^T (G
its Jacobian), v_w = 0 with the motion model's stationary velocity covariance.

Which detections it believes (:mod:`~observer_gym.estimation.target_follower.tracks`, as
the VSE): a chi-square gate on d^T S^-1 d at ``gate_probability``; a detection after a
gap (a missed, dropped or rejected frame) used once the next frame's confirms it; a run
of rejected detections that agree with each other replaces the track. Like the
VSE's reliability rule (spec (6)), the track is lost when its image-state variance at a
capture, diag(H P H^T), exceeds ``reliability_threshold`` or the predicted target is not
in front of the camera.

Output at the step's time, through the camera pose then (``info["camera"]``): the image
state and its target-induced rate (the layout's X_i and X_i^t'), their covariance J P J^T
(J the Jacobian of that map; plus the declared principal-point error of an rgb camera on
(x_i, y_i)); ``tracking_valid`` while there is a track, in front of the camera, and
the image state's variances within ``reliability_threshold``;
``target_visible`` when this step's new frame gave a detection; ``Estimate.nis`` the sum
of d^T S^-1 d over this step's new detections (3 dof each).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from observer_gym.envs.target_follower import TargetFollowerEnv
from observer_gym.envs.target_follower.geometry import MIN_DEPTH_M
from observer_gym.estimation.ekf import ExtendedKalmanFilter
from observer_gym.estimation.filters import UpdateResult
from observer_gym.estimation.latency import CaptureTimeFusion, TimedMeasurement
from observer_gym.estimation.observer import Estimate
from observer_gym.estimation.target_follower.detector import TargetFollowerDetector
from observer_gym.estimation.target_follower.frames import FrameDetection, FrameReader
from observer_gym.estimation.target_follower.latency import GAP_PERIODS
from observer_gym.estimation.target_follower.noise import NoiseRule
from observer_gym.estimation.target_follower.observer import (
    CONFIRM_UPDATES,
    GATE_PROBABILITY,
    RESTART_UPDATES,
)
from observer_gym.estimation.target_follower.state_layout import (
    RobotStep,
    lost_estimate,
    state_estimate,
)
from observer_gym.estimation.target_follower.target_projection import (
    back_project,
    image_state_and_rate,
    project,
)
from observer_gym.estimation.target_follower.tracks import TrackPair, TrackRule

__all__ = ["PixelEKFCore", "PixelEKFObserver", "PixelEKFParams"]


@dataclass(frozen=True)
class PixelEKFParams:
    """The pixel EKF's procedure: its gate and confirmation (as the VSE's,
    :data:`~observer_gym.estimation.target_follower.observer.RULE_PARAMS`) and the
    reliability threshold (px^2, the VSE's, spec (6)). Its noise is the noise rule's."""

    reliability_threshold: float = 4800.0
    gate_probability: float | None = GATE_PROBABILITY
    confirm_updates: int = CONFIRM_UPDATES
    restart_updates: int = RESTART_UPDATES

    def __post_init__(self) -> None:
        if not self.reliability_threshold > 0.0:
            raise ValueError(
                f"PixelEKFParams.reliability_threshold = {self.reliability_threshold!r}: "
                "must be > 0"
            )
        self.track_rule  # noqa: B018  (validates the gate and the confirmation)

    @property
    def track_rule(self) -> TrackRule:
        return TrackRule(self.gate_probability, self.confirm_updates, self.restart_updates)


class PixelEKFCore:
    """The EKF as a :class:`~observer_gym.estimation.latency.FilterCore`; measurements are
    :class:`~observer_gym.estimation.target_follower.frames.FrameDetection` (a None
    detection is a miss). ``nis_of`` maps ``id(measurement)`` to the NIS of its update;
    ``starts`` counts the tracks started and switched to."""

    def __init__(
        self,
        params: PixelEKFParams,
        noise: NoiseRule,
        fx_px: float,
        fy_px: float,
        width_m: float,
        time_s: float,
    ) -> None:
        self.params = params
        self.noise = noise
        self.max_gap_s = GAP_PERIODS * noise.sensor.frame_period_s
        self.last_capture_s = -np.inf
        self.fx_px, self.fy_px, self.width_m = fx_px, fy_px, width_m
        self.tracks: TrackPair[ExtendedKalmanFilter] = TrackPair(params.track_rule)
        self.time_s = float(time_s)
        self.starts = 0
        self.nis_of: dict[int, float] = {}

    @property
    def ekf(self) -> ExtendedKalmanFilter | None:
        """The main track's filter."""
        return self.tracks.main

    def predict_to(self, time_s: float, action: np.ndarray | None) -> None:
        dt = round(time_s - self.time_s, 9)
        if dt <= 0.0:
            return
        tracks = self.tracks.filters()
        if tracks:
            F = np.eye(6)
            F[:3, 3:] = dt * np.eye(3)
            Q = self.noise.world_Q(dt)
            for f in tracks:
                # x <- F x,  P <- F P F^T + Q
                f.predict_nonlinear(F.dot(f.x), F, Q)
        self.time_s = float(time_s)

    # The track rule's start, innovation and update with the detection z (a frame's
    # z_px) of a frame captured with the camera pose T_world_cam.
    def _start(self, z: np.ndarray, T_world_cam: np.ndarray) -> ExtendedKalmanFilter | None:
        if z[2] <= 0.0:
            return None
        p_w, G = back_project(z, T_world_cam, self.fx_px, self.fy_px, self.width_m)
        P0 = np.zeros((6, 6))
        # P_pos = G R G^T, P_vel = Sigma_v (the motion model's stationary velocity)
        P0[:3, :3] = G.dot(self.noise.R(z)).dot(G.T)
        P0[3:, 3:] = self.noise.world_velocity_prior
        return ExtendedKalmanFilter(np.concatenate([p_w, np.zeros(3)]), 0.5 * (P0 + P0.T))

    def _projected(
        self, f: ExtendedKalmanFilter, T_world_cam: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, float]:
        h, H_p, depth_m = project(f.x[:3], T_world_cam, self.fx_px, self.fy_px, self.width_m)
        return h, np.hstack([H_p, np.zeros((3, 3))]), depth_m

    def _innovation(
        self, f: ExtendedKalmanFilter, z: np.ndarray, T_world_cam: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray] | None:
        h, H, depth_m = self._projected(f, T_world_cam)
        if depth_m <= MIN_DEPTH_M:
            return None
        # d = z - h(x), S = H P H^T + R
        return z - h, H.dot(f.P).dot(H.T) + self.noise.R(z)

    def _update(
        self, f: ExtendedKalmanFilter, z: np.ndarray, T_world_cam: np.ndarray
    ) -> UpdateResult:
        h, H, _ = self._projected(f, T_world_cam)
        # x <- x + K d (Joseph form)
        return f.update_nonlinear(z, h, H, self.noise.R(z))

    def update(self, measurement: FrameDetection) -> bool:
        z = measurement.z_px
        gap = measurement.capture_time_s - self.last_capture_s > self.max_gap_s
        self.last_capture_s = measurement.capture_time_s
        if z is None or gap:  # a missed or dropped frame: out of lock, no candidate
            self.tracks.miss()
        if z is None:
            return False
        main = self.tracks.main
        if main is not None:
            _, H, depth_m = self._projected(main, measurement.T_world_cam)
            image_var = np.diag(H.dot(main.P).dot(H.T))
            if depth_m <= MIN_DEPTH_M or np.max(image_var) > self.params.reliability_threshold:
                self.tracks.lose_main()  # lost: a candidate takes its place, or none
        T_world_cam = measurement.T_world_cam
        measured = self.tracks.measure(
            z,
            lambda z_px: self._start(z_px, T_world_cam),
            lambda f, z_px: self._innovation(f, z_px, T_world_cam),
            lambda f, z_px, is_main: self._update(f, z_px, T_world_cam),
        )
        self.starts += measured.event in ("start", "switch")
        if measured.update is not None:
            self.nis_of[id(measurement)] = measured.update.nis
        return measured.used

    def snapshot(self) -> tuple:
        return (self.tracks.snapshot(), self.time_s, self.starts, self.last_capture_s)

    def restore(self, snapshot: tuple) -> None:
        tracks, self.time_s, self.starts, self.last_capture_s = snapshot
        self.tracks.restore(tracks, ExtendedKalmanFilter)


class PixelEKFObserver:
    """The pixel EKF pipeline for TargetFollower (see the module docstring).

    Args:
        env: the TargetFollower env (calibration, obs_mode, latency options).
        params: the gate, confirmation and reliability threshold.
        detector: the rgb detector.
        r_scale: the measurement noise covariance the rule gives, times this (> 0).
    """

    def __init__(
        self,
        env: TargetFollowerEnv,
        params: PixelEKFParams | None = None,
        detector: TargetFollowerDetector | None = None,
        r_scale: float = 1.0,
    ) -> None:
        self.params = params or PixelEKFParams()
        self.noise = NoiseRule.for_env(env, r_scale)
        calibration = env.calibration
        self.fx_px = float(calibration["fx_px"])
        self.fy_px = float(calibration["fy_px"])
        self.width_m = float(calibration["target_width_m"])
        self.delta_y_m = calibration["delta_y_m"]
        self.history_s = env.sensor_spec.history_s(env.config.dt_s)
        self.frames = FrameReader(env, detector, owner="PixelEKFObserver")
        self.reset()

    def reset(self) -> None:
        self.frames.reset()
        # the drive and its core (``fusion.core``, typed as the PixelEKFCore it is)
        self.fusion: CaptureTimeFusion[np.ndarray] | None = None
        self.core: PixelEKFCore | None = None
        self._last_image = np.zeros(3)

    def observe(self, obs: Any, info: dict, action: np.ndarray | None) -> Estimate:
        robot = RobotStep.from_info(info, action, self.delta_y_m)
        if action is None or self.fusion is None:  # after a reset
            core = PixelEKFCore(
                self.params, self.noise, self.fx_px, self.fy_px, self.width_m, robot.time_s
            )
            fusion: CaptureTimeFusion[np.ndarray] = CaptureTimeFusion(
                core, latency_aware=True, history_s=self.history_s
            )
            self.core, self.fusion = core, fusion
        else:
            fusion, started = self.fusion, self.core
            if started is None:  # set with the fusion
                raise RuntimeError("PixelEKFObserver: a drive without its core")
            core = started
        frame = self.frames.newest(obs, info)
        new = [] if frame is None else [TimedMeasurement(frame.capture_time_s, frame)]
        core.nis_of = {}
        used = fusion.step(robot.time_s, action, new)
        visible = frame is not None and frame.z_px is not None
        valid = False
        ekf = core.ekf
        if ekf is not None:
            T_world_cam = np.asarray(info["camera"]["T_world_cam"], dtype=float)
            s, J, depth_m = image_state_and_rate(
                ekf.x, T_world_cam, self.fx_px, self.fy_px, self.width_m
            )
            cov = J.dot(ekf.P).dot(J.T)
            valid = depth_m > MIN_DEPTH_M and bool(
                np.max(np.diag(cov)[:3]) <= self.params.reliability_threshold
            )
        if valid:
            self._last_image = s[:3].copy()
            cov = self.noise.reported(0.5 * (cov + cov.T), s)
            mean, cov = state_estimate(s[:3], s[3:], cov, robot, True, visible)
        else:
            mean, cov = lost_estimate(
                self._last_image, self.params.reliability_threshold, robot, visible
            )
        z = None if frame is None else frame.z_px
        nis = [core.nis_of[id(m.measurement)] for m in new if id(m.measurement) in core.nis_of]
        if nis:
            return Estimate(mean, cov, used, z, robot.time_s, float(sum(nis)), 3 * len(nis))
        return Estimate(mean, cov, used, z, robot.time_s)
