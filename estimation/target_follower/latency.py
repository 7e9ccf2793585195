"""The latency-aware drive of TargetFollower's visual state estimator (``kf-latency``,
``stkf-latency``): each detection is fused at its frame's capture time and the estimate is
predicted to the step's time, when the next action is applied.

:class:`VSECore` is the VSE (:mod:`~observer_gym.estimation.target_follower.filters`, the
spec's procedure) as a :class:`~observer_gym.estimation.latency.FilterCore`, driven by
:class:`~observer_gym.estimation.latency.CaptureTimeFusion` (rewind and replay for late
frames). The spec's step, split at capture times:

- predict (30) over [t, t'] with the velocity u applied over the step that holds the
  interval and B_i at the estimate and the camera's tilt at t (the spec's "B_i at the
  previous estimate", evaluated where the replay is: the tilt moves linearly within a
  step, phi(t) = phi(t_{k-1}) + omega_t (t - t_{k-1}), exactly as the drive moves it);
- update (34) at the capture time (and the self-tuning register (41) on the samples in
  capture order; a dropped or undelivered frame, a gap of more than 1.5 frame periods
  between samples, is a missed sample: it empties the register and ends a candidate track,
  as a missed detection does);
- the reliability check (6) on the estimate at each step time, after the frames captured
  up to it are fused: it is made when the filter first moves on from a step time.

With zero latency (frames captured at the step times and delivered at once) this is the
call sequence of :class:`~observer_gym.estimation.target_follower.observer.
TargetFollowerObserver` (``kf``/``stkf``) and the estimates are the same numbers
(tests/estimation/test_target_follower_observers.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from observer_gym.envs.target_follower import TargetFollowerEnv
from observer_gym.estimation.latency import SAME_TIME_S, CaptureTimeFusion, TimedMeasurement
from observer_gym.estimation.observer import Estimate
from observer_gym.estimation.target_follower.detector import TargetFollowerDetector
from observer_gym.estimation.target_follower.filters import VisualStateEstimator, VSEParams
from observer_gym.estimation.target_follower.frames import FrameDetection, FrameReader
from observer_gym.estimation.target_follower.models import (
    TargetFollowerCameraParams,
    robot_jacobian,
)
from observer_gym.estimation.target_follower.observer import estimator_setup
from observer_gym.estimation.target_follower.state_layout import (
    RobotStep,
    lost_estimate,
    state_estimate,
)

__all__ = ["HeldInput", "LatencyAwareObserver", "VSECore"]

# A gap between successive samples longer than this many frame periods is a missed sample.
GAP_PERIODS = 1.5


@dataclass(frozen=True)
class HeldInput:
    """The robot's input over one step interval (t_{k-1}, t_k]: the applied velocity and
    where the tilt started, so the tilt is known at any time inside it."""

    applied: np.ndarray  # (v, omega, omega_t)
    start_time_s: float  # t_{k-1}
    end_time_s: float  # t_k
    start_tilt_rad: float  # phi(t_{k-1})

    def tilt_at(self, time_s: float) -> float:
        """phi(t) = phi(t_{k-1}) + omega_t (t - t_{k-1})."""
        return self.start_tilt_rad + float(self.applied[2]) * (time_s - self.start_time_s)


@dataclass(frozen=True)
class _Snapshot:
    vse: tuple  # VisualStateEstimator.snapshot()
    last_sample_s: float
    time_s: float
    check_due: bool


class VSECore:
    """The visual state estimator as a capture-time
    :class:`~observer_gym.estimation.latency.FilterCore` (see the module docstring).
    Measurements are :class:`~observer_gym.estimation.target_follower.frames.FrameDetection`
    (a None detection is a missed one); ``nis_of`` maps ``id(measurement)`` to the NIS of
    its latest update."""

    def __init__(
        self,
        vse: VisualStateEstimator,
        camera_params: TargetFollowerCameraParams,
        time_s: float,
        frame_period_s: float,
    ) -> None:
        self.vse = vse
        self.camera_params = camera_params
        self.time_s = float(time_s)
        self.max_gap_s = GAP_PERIODS * frame_period_s
        self.last_sample_s = -np.inf
        self.check_due = False  # the filter sits at a step time not yet checked (6)
        self.nis_of: dict[int, float] = {}

    def predict_to(self, time_s: float, action: HeldInput | None) -> None:
        vse = self.vse
        dt_s = round(time_s - self.time_s, 9)
        if dt_s <= 0.0:
            return
        if self.check_due and vse.initialised:  # (6) at the step time being left
            vse.check_reliability()
        self.check_due = False
        if action is not None:
            if vse.tracks.filters():
                # (30) over dt with B_i at each track's estimate and the tilt now (the
                # filter's time lies in the step interval of ``action``)
                tilt_rad, params = action.tilt_at(self.time_s), self.camera_params

                def B_i(X_i: np.ndarray) -> np.ndarray:
                    return robot_jacobian(X_i, tilt_rad, params)

                vse.predict(B_i, action.applied, dt_s, tilt_rad)
            self.check_due = abs(time_s - action.end_time_s) < SAME_TIME_S
        self.time_s = float(time_s)

    def update(self, measurement: FrameDetection) -> bool:
        vse = self.vse
        z = measurement.z_px
        if z is None:
            vse.measure(None)  # a missed sample
            return False
        if measurement.capture_time_s - self.last_sample_s > self.max_gap_s:
            vse.miss()  # samples missed in between: the register and a candidate end
        used = vse.measure(z)  # (2), (3), (5)
        self.last_sample_s = measurement.capture_time_s
        if vse.last_update is not None:
            self.nis_of[id(measurement)] = vse.last_update.nis
        return used

    def snapshot(self) -> _Snapshot:
        return _Snapshot(self.vse.snapshot(), self.last_sample_s, self.time_s, self.check_due)

    def restore(self, snapshot: _Snapshot) -> None:
        self.vse.restore(snapshot.vse)
        self.last_sample_s = snapshot.last_sample_s
        self.time_s = snapshot.time_s
        self.check_due = snapshot.check_due

    @property
    def reliable(self) -> bool:
        """A track with every diagonal element of P within the threshold (6)."""
        return self.vse.valid


class LatencyAwareObserver:
    """TargetFollower's VSE fused at capture time (``kf-latency``, ``stkf-latency``).

    Args:
        env: the TargetFollower env (calibration, obs_mode, latency options).
        filter: "stkf" (self-tuning R) or "kf" (the rule's R).
        params: the spec's procedure with Table 1's noise (default: the noise rule,
            :data:`~observer_gym.estimation.target_follower.observer.RULE_PARAMS`);
            ``self_tuning`` is set from ``filter``.
        camera_params: the f_x, f_y, W, delta_y that B_i uses (default: the calibration).
        detector: the rgb detector.
        r_scale: the measurement noise covariance the rule gives, times this (> 0).

    The history of step times kept for late frames is the declared sensor's
    (``env.sensor_spec.history_s``).

    The output is :class:`~observer_gym.estimation.target_follower.observer.
    TargetFollowerObserver`'s: the estimate at the step time, ``tracking_valid`` while it
    is reliable (else the last reliable image state with zero rates and covariance
    threshold x I), ``target_visible`` when this step's new frame gave a detection,
    ``Estimate.nis`` the sum over this step's new detections (3 dof each).
    """

    def __init__(
        self,
        env: TargetFollowerEnv,
        filter: str = "stkf",
        params: VSEParams | None = None,
        camera_params: TargetFollowerCameraParams | None = None,
        detector: TargetFollowerDetector | None = None,
        r_scale: float = 1.0,
    ) -> None:
        self.params, self.noise = estimator_setup(env, filter, params, r_scale, False)
        self.filter = filter
        self.camera_params = camera_params or TargetFollowerCameraParams.from_calibration(
            env.calibration
        )
        self.delta_y_m = env.calibration["delta_y_m"]
        self.frame_period_s = env.sensor_spec.frame_period_s
        self.history_s = env.sensor_spec.history_s(env.config.dt_s)
        self.frames = FrameReader(env, detector, owner="LatencyAwareObserver")
        self.reset()

    def reset(self) -> None:
        self.frames.reset()
        # the drive and its core (``fusion.core``, typed as the VSECore it is)
        self.fusion: CaptureTimeFusion[HeldInput] | None = None
        self.core: VSECore | None = None
        self._robot: RobotStep | None = None
        self._last_image = np.zeros(3)

    def observe(self, obs: Any, info: dict, action: np.ndarray | None) -> Estimate:
        robot = RobotStep.from_info(info, action, self.delta_y_m)
        held: HeldInput | None
        if action is None or self.fusion is None:  # after a reset
            core = VSECore(
                VisualStateEstimator(self.params, self.noise),
                self.camera_params,
                robot.time_s,
                self.frame_period_s,
            )
            fusion: CaptureTimeFusion[HeldInput] = CaptureTimeFusion(
                core, latency_aware=True, history_s=self.history_s
            )
            self.core, self.fusion = core, fusion
            held = None
        else:
            fusion, started, prev = self.fusion, self.core, self._robot
            if started is None or prev is None:  # both set with the fusion
                raise RuntimeError("LatencyAwareObserver: a drive without its core or last step")
            core = started
            held = HeldInput(robot.applied, prev.time_s, robot.time_s, prev.tilt_rad)
        self._robot = robot
        frame = self.frames.newest(obs, info)
        new = [] if frame is None else [TimedMeasurement(frame.capture_time_s, frame)]
        core.nis_of = {}
        used = fusion.step(robot.time_s, held, new)
        vse = core.vse
        visible = frame is not None and frame.z_px is not None
        kf = vse.kf if core.reliable else None  # the main track's filter, while reliable
        if kf is not None:
            self._last_image = kf.x[:3].copy()
            P = vse.noise.reported(kf.P, kf.x)
            mean, cov = state_estimate(kf.x[:3], kf.x[3:], P, robot, True, visible)
        else:
            mean, cov = lost_estimate(
                self._last_image, self.params.reliability_threshold, robot, visible
            )
        z = None if frame is None else frame.z_px
        nis = [core.nis_of[id(m.measurement)] for m in new if id(m.measurement) in core.nis_of]
        if nis:
            return Estimate(mean, cov, used, z, robot.time_s, float(sum(nis)), 3 * len(nis))
        return Estimate(mean, cov, used, z, robot.time_s)
