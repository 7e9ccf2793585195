"""BallCatcher's ``ekf``: an extended Kalman filter on the ball's pixels, fused at capture time.

State x = (p, v): the ball's position and velocity in the world (m, m/s, z up). Process:
:class:`~observer_gym.estimation.ball_catcher.models.BallFlight`, gravity known and the
env's quadratic air drag when the env has it (``air_drag=True``), white acceleration noise
``accel_noise_std`` as the viewline filter's. Measurement: the ball's pixel (u, v) in each
detected frame through that frame's nominal pinhole model (``info["frames"][i]["K"]``,
``["T_world_cam"]``), with q = K R^T (p - t) (R, t: ``T_world_cam``'s rotation and
camera centre):

    h(x) = (q1 / q3, q2 / q3),   H = dh/dp = [[1/q3, 0, -q1/q3^2], [0, 1/q3, -q2/q3^2]] K R^T

(zero for the velocity), R = ``pixel_std_px``^2 I. A :class:`LandmarkMeasurement` (a point
of known world position: the self-calibrating observers' box hole) has the same h with
that point for p, and H zero on the ball. The declared calibration uncertainty
enters as consider parameters (:mod:`~observer_gym.estimation.ball_catcher.
calibration_consider`): each frame's pixel also carries J c_camera, J = dh/dc of the
pixel model along each calibration parameter of the frame's camera at the linearisation
point; the iteration below runs on the augmented state with c held at 0. Parameters that
the calibration object marks as estimated (``CalibrationConsider(estimated=...)``, the
self-calibrating observers) are states instead: the frame is projected through the
camera they describe and they are iterated with the ball.

The viewline filter (``kf``) instead turns each pixel into two planes through the camera
centre, which are linear in p, so it needs no linearisation; this filter linearises the
projection. The outlier gate is the same p-sigma test (27)-(30), on the pixel innovation.

Iterated update (Gauss-Newton, the IEKF): the projection is relinearised at the updated
estimate, x_{i+1} = x0 + K_i (y - h(x_i) - H_i (x0 - x_i)) with K_i = P0 H_i^T
(H_i P0 H_i^T + R)^-1, up to ``iterations`` linearisations (default 5; 1 is the plain
EKF) or until no entry moves more than ITERATION_TOL; the final update is
:meth:`ExtendedKalmanFilter.update` at the last linearisation (gated, Joseph form).

Prior: the declared throw distribution's
(:func:`~observer_gym.estimation.ball_catcher.observer.throw_prior`), as the viewline
filter's. A restart (below) starts from its mean with standard deviations 1 m and 3 m/s
(``initial_std_pos_m``, ``initial_std_vel_mps``), not the viewline filter's 10 m and
10 m/s (still 17 and 6 times the default throws' spread of +-0.1 m and about 0.5 m/s).
Both measured over 40 flights, position RMSE from 0.2 s to the box (random_offsets /
alternating at 60 ms latency), when every flight started from such a prior: the 10 m
prior diverged (0.7 m / 0.3 m plain, worse iterated); the 1 m prior with the plain EKF
still diverged on a few flights (0.21 m / 0.09 m); iterated, 3.6 / 6.0 mm (kf 3.6 /
6.5 mm over 100 flights). The early frames of unsynchronised cameras each fix only a
viewline, along which a wide prior leaves the linearisation point far off.

Timing: every frame is fused at its capture time, frames delivered late (latency, jitter,
cameras out of order) included, by :class:`~observer_gym.estimation.latency.CaptureTimeFusion`
(rewind to the step before the capture and replay), and the estimate reported at each step
is the filter's at the step's time (the time the next action is applied). The kept history
covers the latest delivery of the declared sensor (``env.sensor_spec.history_s``: its
latency, the preset's spread, five jitter standard deviations and two control steps).

Re-acquisition, as the viewline filter's observer
(:class:`~observer_gym.estimation.ball_catcher.observer.BallCatcherObserver`, whose module
docstring says why): when ``reacquire_after`` (default 3, ``DEFAULT_REACQUIRE_AFTER``)
detections of one camera in a row are not used (frames of other cameras in between do not
break the run; frames without a detection neither break nor extend it), the estimate is
taken as lost: the filter restarts from the restart prior above at time 0 and fuses again, at
their capture times and each gate decision made anew, every detection delivered so far
that was captured at or after the first frame of that run (all cameras'), then predicts to
the step's time. ``reacquisitions`` counts the restarts. Not used means gated out, or
skipped because the estimate is not in front of the frame's camera (below): for this
filter that also says the estimate is lost (the viewline filter never skips). The
observer keeps every detection captured since the oldest open run's first frame, and at
least ``history_s`` back, for that. The decisions that count are those of the step a
frame is delivered in (a late frame's at its capture time), as for the viewline filter.
Without the restart, at ``image_noise_std`` = 64 (rendered frames) the filter kept the
false detections its first frames accepted under the wide prior and gated out every true
one after: seeds 0 and 1 missed, 14 and 2.7 m off at the end; with it both are caught,
and from 0.2 s on at most 3.0 mm off and within 3 claimed std
(tests/estimation/test_ball_catcher_restart.py).

Not here: the paper's stacked per-tick update. A linearisation point less than
``MIN_DEPTH_M`` in front of a frame's camera makes that frame unusable (the projection has
no useful linearisation there): it is skipped, not fused (the iteration stops at the last
point in front).
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass
from typing import Any

import numpy as np

from observer_gym.envs.ball_catcher import BallCatcherEnv
from observer_gym.estimation.ball_catcher.calibration_consider import CalibrationConsider
from observer_gym.estimation.ball_catcher.detector import BallCatcherDetector
from observer_gym.estimation.ball_catcher.filters import DEFAULT_GATE_P
from observer_gym.estimation.ball_catcher.frames import FrameReader
from observer_gym.estimation.ball_catcher.models import BallFlight, env_drag_per_m
from observer_gym.estimation.ball_catcher.observer import (
    ACCEL_NOISE_STD,
    DEFAULT_REACQUIRE_AFTER,
    RejectionRuns,
    calibration_consider,
    checked_reacquire_after,
    default_pixel_std_px,
    initial_estimate,
)
from observer_gym.estimation.ball_catcher.state_layout import state_estimate
from observer_gym.estimation.ekf import ExtendedKalmanFilter
from observer_gym.estimation.filters import UpdateResult
from observer_gym.estimation.gating import PSigmaGate
from observer_gym.estimation.latency import CaptureTimeFusion, TimedMeasurement
from observer_gym.estimation.observer import Estimate
from observer_gym.estimation.viewline import MIN_DEPTH_M

__all__ = [
    "LandmarkMeasurement",
    "PixelEKFCore",
    "PixelEKFObserver",
    "PixelMeasurement",
    "pixel_model",
]

INITIAL_STD_POS_M = 1.0  # the prior's standard deviations (see the module docstring)
INITIAL_STD_VEL_MPS = 3.0
DEFAULT_ITERATIONS = 5  # linearisations per update at most (1: the plain EKF)
ITERATION_TOL = 1e-6  # the iteration stops when no state entry moves more (m, m/s)


@dataclass(frozen=True, slots=True)
class PixelMeasurement:
    """One frame's detection: camera, nominal K (3, 3), ``T_world_cam`` (4, 4) and the
    ball's pixel ``uv_px`` (2,)."""

    camera_id: Any
    K: np.ndarray
    T_world_cam: np.ndarray
    uv_px: np.ndarray


@dataclass(frozen=True, slots=True)
class LandmarkMeasurement:
    """A point of known world position ``point_world`` (3,) (m; the box's hole, from the
    robot's kinematics) detected at ``uv_px`` (2,) in a frame of ``camera_id`` (nominal K,
    ``T_world_cam``): it measures only the camera's calibration parameters."""

    camera_id: Any
    K: np.ndarray
    T_world_cam: np.ndarray
    uv_px: np.ndarray
    point_world: np.ndarray


def pixel_model(
    K: np.ndarray, T_world_cam: np.ndarray, pos_world_m: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float]:
    """(h (2,), H_pos (2, 3), depth_m): the pixel of the world point ``pos_world_m``, its
    Jacobian with respect to the point, and q3 (the depth along the optical axis for a K
    with last row (0, 0, 1)); see the module docstring."""
    T = np.asarray(T_world_cam, dtype=float)
    # q = K R^T (p - t)
    KRt = np.asarray(K, dtype=float) @ T[:3, :3].T
    q = KRt @ (np.asarray(pos_world_m, dtype=float) - T[:3, 3])
    inv_q3 = 1.0 / q[2]
    # h = (q1 / q3, q2 / q3)
    uv = q[:2] * inv_q3
    # dh/dq = [[1/q3, 0, -q1/q3^2], [0, 1/q3, -q2/q3^2]]; dq/dp = K R^T
    dh_dq = np.array([[inv_q3, 0.0, -uv[0] * inv_q3], [0.0, inv_q3, -uv[1] * inv_q3]])
    return uv, dh_dq @ KRt, float(q[2])


@dataclass(frozen=True, slots=True)
class _Snapshot:
    time_s: float
    x: np.ndarray
    P: np.ndarray
    accepted: int
    rejected: int


class PixelEKFCore:
    """The pixel EKF as a :class:`~observer_gym.estimation.latency.FilterCore`: ``ekf.x``,
    ``ekf.P`` at ``time_s`` (with ``calibration``: the augmented state, ``x`` and ``P``
    the ball's part), iterated updates (see the module docstring). ``results`` maps
    ``id(measurement)`` to the :class:`UpdateResult` of its latest update; a measurement
    whose latest update skipped it (not in front of the camera) has no entry (the observer
    drops the entries of the measurements it no longer keeps)."""

    ekf: ExtendedKalmanFilter
    flight: BallFlight
    iterations: int
    R_px2: np.ndarray
    time_s: float

    def __init__(
        self,
        x0: np.ndarray,
        P0: np.ndarray,
        flight: BallFlight,
        pixel_std_px: float,
        gate_p: float | None = DEFAULT_GATE_P,
        time_s: float = 0.0,
        iterations: int = DEFAULT_ITERATIONS,
        calibration: CalibrationConsider | None = None,
    ) -> None:
        if not (np.isfinite(pixel_std_px) and pixel_std_px > 0.0):
            raise ValueError(f"PixelEKFCore: pixel_std_px = {pixel_std_px!r}, must be > 0")
        self.calibration = calibration if calibration is not None and calibration.active else None
        if (
            isinstance(iterations, bool)
            or not isinstance(iterations, numbers.Integral)
            or iterations < 1
        ):
            raise ValueError(f"PixelEKFCore: iterations = {iterations!r}, must be an integer >= 1")
        self.iterations = int(iterations)
        gate = None if gate_p is None else PSigmaGate(gate_p)
        x0 = np.array(x0, dtype=float).reshape(-1)
        P0 = np.array(P0, dtype=float)
        if x0.shape != (6,) or P0.shape != (6, 6):
            raise ValueError(f"PixelEKFCore: x0 {x0.shape}, P0 {P0.shape}; expected (6,), (6, 6)")
        if self.calibration is not None:
            x0, P0 = self.calibration.augmented(x0, P0)
        self.ekf = ExtendedKalmanFilter(x0, P0, gate)
        self.flight = flight
        self.R_px2 = float(pixel_std_px) ** 2 * np.eye(2)
        self.time_s = float(time_s)
        self.results: dict[int, UpdateResult] = {}

    def predict_to(self, time_s: float, action: np.ndarray | None = None) -> None:
        """Predict to ``time_s`` (>= ``time_s``); the ball ignores the robot's action."""
        dt_s = float(time_s) - self.time_s
        if dt_s < 0.0:
            raise ValueError(
                f"PixelEKFCore.predict_to: {time_s!r} s is before the estimate's time "
                f"{self.time_s!r} s"
            )
        if dt_s == 0.0:
            return
        x_next, F, Q = self.flight.propagate(self.ekf.x[:6], dt_s)
        if self.calibration is not None:  # the offsets are constant
            F, Q, _ = self.calibration.transition(F, Q)
            x_next = np.concatenate([x_next, self.ekf.x[6:]])
        self.ekf.predict_nonlinear(x_next, F, Q)  # x <- f(x), P <- F P F^T + R1
        self.time_s = float(time_s)

    @property
    def x(self) -> np.ndarray:
        """The ball's estimate (6,) at ``time_s`` (``ekf.x`` itself without consider
        parameters)."""
        return self.ekf.x if self.calibration is None else self.ekf.x[:6]

    @property
    def P(self) -> np.ndarray:
        """Its covariance (6, 6), the calibration offsets' effect included (``ekf.P``
        itself without consider parameters)."""
        return self.ekf.P if self.calibration is None else self.ekf.P[:6, :6]

    def _linearised(self, m: PixelMeasurement | LandmarkMeasurement, x: np.ndarray):
        """(h(x), H (2, dim)) at ``x`` (with ``calibration``: the camera's offsets' J in
        its columns, and the camera moved by its estimated parameters), or None when the
        point is not MIN_DEPTH_M in front of the camera. A landmark's point is known: H
        is zero on the ball."""
        landmark = isinstance(m, LandmarkMeasurement)
        position_m = np.array(m.point_world if isinstance(m, LandmarkMeasurement) else x[:3])
        calibration = self.calibration
        K, T = m.K, m.T_world_cam
        if calibration is not None and calibration.estimated:
            K, T = calibration.camera_at(x, m.camera_id, K, T)
        h_x, H_pos, depth_m = pixel_model(K, T, position_m)
        if not depth_m > MIN_DEPTH_M:
            return None
        H = np.zeros((2, 6))
        if not landmark:
            H[:, :3] = H_pos
        if calibration is None:
            return h_x, H

        def pixel_px(K: np.ndarray, T_world_cam: np.ndarray) -> np.ndarray | None:
            # the pixel of the linearisation point through a camera (K, T_world_cam)
            uv, _, depth = pixel_model(K, T_world_cam, position_m)
            return uv if depth > MIN_DEPTH_M else None

        # h = h(x) + J c_camera (calibration_consider)
        J = calibration.jacobian(pixel_px, K, T)
        if J is None:
            return None
        return h_x, calibration.rows(H, J, m.camera_id)

    def update(self, measurement: PixelMeasurement | LandmarkMeasurement) -> bool:
        """Fuse one frame's pixel at the current time, iterated (see the module docstring);
        whether it was used (False: gated out, or the predicted position is not in front of
        the camera)."""
        ekf = self.ekf
        x_prior, P_prior = ekf.x, ekf.P
        y = measurement.uv_px
        x_lin = x_prior
        linearised = self._linearised(measurement, x_lin)
        if linearised is None:
            self.results.pop(id(measurement), None)  # skipped (not gated): no result
            return False
        for _ in range(self.iterations - 1):
            h_x, H = linearised
            # Gauss-Newton step: x' = x0 + K (y - h(x) - H (x0 - x)), K = P0 H^T S^-1
            PHt = P_prior @ H.T
            S = H @ PHt + self.R_px2
            x_next = x_prior + PHt @ np.linalg.solve(S, y - h_x - H @ (x_prior - x_lin))
            if self.calibration is not None:  # consider parameters stay at 0
                x_next[self.calibration.considered_index] = 0.0
            step_m = float(np.max(np.abs(x_next - x_lin)))
            relinearised = self._linearised(measurement, x_next)
            if relinearised is None:
                break
            x_lin, linearised = x_next, relinearised
            if step_m < ITERATION_TOL:
                break
        h_x, H = linearised
        # The EKF update linearised at x_lin: pseudo-measurement y - h(x_lin) + H x_lin,
        # innovation y - h(x_lin) - H (x0 - x_lin); gated, Joseph form
        result = ekf.update(y - h_x + H @ x_lin, H, self.R_px2)
        if self.calibration is not None:
            ekf.x, ekf.P = self.calibration.reset_consider(ekf.x, ekf.P)
        self.results[id(measurement)] = result
        return result.accepted

    def snapshot(self) -> _Snapshot:
        # The EKF assigns fresh arrays at every step, so the snapshot's stay intact.
        ekf = self.ekf
        return _Snapshot(self.time_s, ekf.x, ekf.P, ekf.accepted_count, ekf.rejected_count)

    def restore(self, snapshot: _Snapshot) -> None:
        ekf = self.ekf
        ekf.x, ekf.P = snapshot.x, snapshot.P
        ekf.accepted_count, ekf.rejected_count = snapshot.accepted, snapshot.rejected
        self.time_s = snapshot.time_s


class PixelEKFObserver:
    """Detector + pixel EKF for BallCatcher-v1 (observer ``ekf``; see the module docstring).

    Args:
        env: the (unwrapped) BallCatcher env, made with obs_mode "rgb" or "measurements".
        pixel_std_px: the pixel noise (default: the viewline filter's,
            :func:`~observer_gym.estimation.ball_catcher.observer.default_pixel_std_px`).
        gate_p: p of the outlier test (30) on the pixel innovation; None: no gate.
        accel_noise_std: the model's white acceleration noise (m/s^2 per sqrt(s)).
        drag: model the env's air drag (default: whether the env has it).
        detector: the rgb detector (default :class:`BallCatcherDetector`).
        history_s: how far back late frames are fused at their capture time (default
            ``env.sensor_spec.history_s(control_dt_s)``, the declared sensor's).
        iterations: linearisations per update at most (1: the plain EKF).
        initial_std_pos_m, initial_std_vel_mps: the restart prior's standard deviations
            (see the module docstring; the first prior is the throw distribution's).
        r_scale: the default pixel noise's R times this (> 0; sensitivity studies).
        reacquire_after: detections of one camera in a row not used after which the
            filter restarts from the prior and those frames (see the module docstring); an
            integer >= 1.
        consider_calibration: carry the declared calibration uncertainty as consider
            parameters (default True; False leaves it out, to show its effect).
    """

    def __init__(
        self,
        env: BallCatcherEnv,
        pixel_std_px: float | None = None,
        gate_p: float | None = DEFAULT_GATE_P,
        accel_noise_std: float = ACCEL_NOISE_STD,
        drag: bool | None = None,
        detector: BallCatcherDetector | None = None,
        history_s: float | None = None,
        iterations: int = DEFAULT_ITERATIONS,
        initial_std_pos_m: float = INITIAL_STD_POS_M,
        initial_std_vel_mps: float = INITIAL_STD_VEL_MPS,
        r_scale: float = 1.0,
        reacquire_after: int = DEFAULT_REACQUIRE_AFTER,
        consider_calibration: bool = True,
    ) -> None:
        if not isinstance(env, BallCatcherEnv):
            raise ValueError(f"PixelEKFObserver needs a BallCatcherEnv, got {type(env).__name__}")
        self.calibration = calibration_consider(env, consider_calibration)
        self.reacquire_after = checked_reacquire_after(reacquire_after, "PixelEKFObserver")
        cfg = env.config
        self.pixels = FrameReader(cfg, detector, owner="PixelEKFObserver")
        self.pixel_std_px = float(
            default_pixel_std_px(env, r_scale) if pixel_std_px is None else pixel_std_px
        )
        self.gate_p = gate_p
        drag = cfg.air_drag if drag is None else bool(drag)
        self.flight = BallFlight(env_drag_per_m(drag), accel_noise_std)
        spec_history_s = env.sensor_spec.history_s(cfg.control_dt_s)
        self.history_s = float(spec_history_s if history_s is None else history_s)
        self.iterations = iterations
        self.x0, self.P0 = initial_estimate(cfg)
        self.x_lost = self.x0  # a restart's prior
        self.P_lost = np.diag([initial_std_pos_m**2] * 3 + [initial_std_vel_mps**2] * 3)
        self.reset()

    def reset(self) -> None:
        self.core = self._new_core(self.x0, self.P0)
        self.fusion = CaptureTimeFusion(self.core, latency_aware=True, history_s=self.history_s)
        self._rejected = RejectionRuns(self.reacquire_after)
        self.reacquisitions = 0
        # every detection delivered and still needed for a restart (see _forget)
        self._kept: list[TimedMeasurement] = []

    def _new_core(self, x0: np.ndarray, P0: np.ndarray) -> PixelEKFCore:
        """The filter at the prior (``x0``, ``P0``), at time 0."""
        return PixelEKFCore(
            x0,
            P0,
            self.flight,
            self.pixel_std_px,
            self.gate_p,
            time_s=0.0,
            iterations=self.iterations,
            calibration=self.calibration,
        )

    def observe(self, obs: Any, info: dict, action: np.ndarray | None) -> Estimate:
        reports, timed = [], []
        for frame in info["frames"]:
            uv = self.pixels.detect(frame)
            reports.append({"camera_id": frame["camera_id"], "uv_px": uv})
            if uv is not None:
                m = PixelMeasurement(frame["camera_id"], frame["K"], frame["T_world_cam"], uv)
                timed.append(TimedMeasurement(float(frame["capture_time_s"]), m))
        now_s = float(info["time_s"])
        landmarks = self._landmarks(info)
        self._kept.extend(timed + landmarks)
        used = self.fusion.step(now_s, action, timed + landmarks)
        # The run of each camera, frame by frame in capture order (as the viewline
        # filter's observer adds them); a restart fuses this step's later frames again.
        for tm in sorted(timed, key=lambda t: t.capture_time_s):
            used |= self._count(tm, now_s, action)
        # NIS of this step's accepted frames (each at its capture time), 2 per frame
        results = [self.core.results.get(id(m.measurement)) for m in timed]
        accepted = [r for r in results if r is not None and r.accepted]
        self._forget(now_s)
        mean, covariance = state_estimate(self.core.x, self.core.P, info)
        return Estimate(
            mean=mean,
            covariance=covariance,
            measurement_used=used,
            measurement=reports or None,
            time_s=now_s,
            nis=float(sum(r.nis for r in accepted)) if accepted else None,
            nis_dof=2 * len(accepted),
        )

    def _landmarks(self, info: dict) -> list[TimedMeasurement]:
        """This step's landmark detections (:class:`LandmarkMeasurement`), fused with the
        frames at their capture times but not counted in the cameras' runs; none here
        (the self-calibrating observers add the box's hole)."""
        return []

    def _count(self, m: TimedMeasurement, now_s: float, action: np.ndarray | None) -> bool:
        """Extend or end the run of ``m``'s camera by its latest decision; restart after
        ``reacquire_after`` in a row. Whether a restart used any frame fused again."""
        result = self.core.results.get(id(m.measurement))
        camera = m.measurement.camera_id
        if result is not None and result.accepted:
            self._rejected.used(camera)
            return False
        since_s = self._rejected.not_used(camera, m.capture_time_s)
        if since_s is None:
            return False
        return self._restart(since_s, now_s, action)

    def _restart(self, since_s: float, now_s: float, action: np.ndarray | None) -> bool:
        """Start over from the restart prior at time 0 and fuse again every kept detection captured
        at or after ``since_s``, predicted to ``now_s``. The counters are those before the
        first detection fused again plus its new decisions (as the viewline filter's), so
        ``accepted_count + rejected_count`` still counts each decided detection once.
        Whether any detection fused again was used."""
        old = self.core
        again = [m for m in self._kept if m.capture_time_s >= since_s]
        redone = [old.results.get(id(m.measurement)) for m in again]
        core = self._new_core(self.x_lost, self.P_lost)
        core.ekf.accepted_count = old.ekf.accepted_count - sum(
            r is not None and r.accepted for r in redone
        )
        core.ekf.rejected_count = old.ekf.rejected_count - sum(
            r is not None and not r.accepted for r in redone
        )
        again_ids = {id(m.measurement) for m in again}
        core.results = {k: r for k, r in old.results.items() if k not in again_ids}
        self.core = core
        self.fusion = CaptureTimeFusion(core, latency_aware=True, history_s=self.history_s)
        self.reacquisitions += 1
        return self.fusion.step(now_s, action, again)

    def _forget(self, now_s: float) -> None:
        """Keep the detections a restart can still fuse again: those captured since the
        oldest open run's first frame, and every one of the last ``history_s`` (a frame
        delivered later can start a run that far back)."""
        oldest_s = self._rejected.oldest_start_s(now_s - self.history_s)
        self._kept = [m for m in self._kept if m.capture_time_s >= oldest_s]
        kept_ids = {id(m.measurement) for m in self._kept}
        core = self.core
        core.results = {k: r for k, r in core.results.items() if k in kept_ids}
