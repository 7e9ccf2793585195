"""BallCatcher's viewline Kalman filter: a flying ball tracked from unsynchronised frames.

docs/spec/catcher.md (Linderoth et al., ICRA 2010): each detected image point gives two
viewline rows (observer_gym.estimation.viewline, (17)-(22)); several frames of one control
interval can be stacked with time-offset rows (23)-(26); outliers are rejected by the
p-sigma test (27)-(30). The process model is
:class:`~observer_gym.estimation.ball_catcher.models.BallisticModel` (world frame z up; the
paper's has y up).

Beyond the paper: the filter predicts exactly (Phi, Gamma, R1 of the actual interval) to
each frame's capture time, so aperiodic frames need no offset rows (:meth:`add_frame`);
the paper's stacked form is :meth:`ViewlineKalmanFilter.add_frames_at_tick`. Beside the
viewline rows, one measurement model of another kind: a 3-D position of the ball
(:meth:`ViewlineKalmanFilter.add_position`, H = [I 0], for the ``learned-kf`` observer
whose network reports a position and its covariance instead of a pixel). Frames
that arrive late (latency) are re-filtered exactly from a short history of estimates, and
:meth:`ViewlineKalmanFilter.predicted` reads the estimate at any later time without
changing the filter (the class docstring says how). The declared calibration uncertainty
enters as consider parameters (``calibration``,
:mod:`~observer_gym.estimation.ball_catcher.calibration_consider`).
"""

from __future__ import annotations

import bisect
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from observer_gym.estimation.ball_catcher.calibration_consider import CalibrationConsider
from observer_gym.estimation.ball_catcher.models import BallisticModel
from observer_gym.estimation.camera_geometry import projection_matrix
from observer_gym.estimation.filters import KalmanFilter, UpdateResult
from observer_gym.estimation.gating import PSigmaGate
from observer_gym.estimation.viewline import (
    CameraFrame,
    viewline_noise_std,
    viewline_rows,
)

__all__ = ["DEFAULT_GATE_P", "DEFAULT_HISTORY_S", "ViewlineKalmanFilter"]

# p of the outlier test (30). For an isotropic 2x2 S, ||d||^2 / sigma^2 is chi-square with
# 2 degrees of freedom, so a good point is rejected with probability exp(-p^2 / 2): 0.22 %
# at p = 3.5 (one false rejection per ~450 frames, which costs only that frame), while a
# detection on the wrong object, tens of pixels off, is still far outside.
DEFAULT_GATE_P = 3.5

DEFAULT_HISTORY_S = 1.0  # how far back late frames are re-filtered exactly (see below)


@dataclass(slots=True)
class _Checkpoint:
    """The filter's estimate and counters at ``time_s`` (after an entry, or initial)."""

    time_s: float
    x: np.ndarray
    P: np.ndarray
    accepted: int
    rejected: int


@dataclass(slots=True)
class _Position:
    """A measured ball position y (3,) (m) and its covariance R (3, 3) (m^2)."""

    y_m: np.ndarray
    R_m2: np.ndarray


@dataclass(slots=True)
class _Entry:
    """One processed measurement: a single frame at its capture time (:meth:`add_frame`),
    a stack of frames at a control tick (:meth:`add_frames_at_tick`) or a position
    (:meth:`add_position`, ``frames`` empty), with the estimate right after it
    (``after``) and the single frame's camera."""

    time_s: float
    frames: tuple[CameraFrame, ...]
    stacked: bool
    after: _Checkpoint
    camera: int = 0
    position: _Position | None = None


def _detected(frame: CameraFrame) -> np.ndarray:
    """A fused frame's pixels; the filter takes only frames with a detection."""
    if frame.uv_px is None:
        raise ValueError(
            "ViewlineKalmanFilter: a frame without a detection (uv_px None) reached an "
            "update; a frame without a detection is not fused"
        )
    return frame.uv_px


class ViewlineKalmanFilter:
    """Kalman filter (filter form (5)-(7)) on :class:`BallisticModel` with viewline rows.

    ``x`` = (x, y, z, vx, vy, vz) (m, m/s, world frame, z up) and ``P`` are the estimate
    at ``time_s``. Counts of used and gated-out detections: ``accepted_count``,
    ``rejected_count``.

    - ``pixel_std_px``: detector noise (px), mapped to R2 by :func:`viewline_noise_std`.
    - ``gate_p``: p of the outlier test (27)-(30), :data:`DEFAULT_GATE_P`; None: no gate.
    - ``accel_noise_std``: white acceleration noise of the model, m/s^2 per sqrt(s)
      (intensity m^2/s^3), see :class:`BallisticModel`. It blurs gravity, and gravity is
      all that fixes a single camera's depth: keep it as small as the real flight allows
      (docs/linderoth2010.md).
    - ``history_s``: how long measurements are kept for late frames (below).
    - ``calibration``: the cameras' declared calibration uncertainty as consider
      parameters (:class:`CalibrationConsider`); None or one with nothing uncertain: the
      filter runs on the 6 entries alone. With it the filter's ``KalmanFilter`` holds the
      augmented state (``kf.x``, ``kf.P``), ``x`` and ``P`` are the ball's part, and
      :meth:`add_frame` takes the frame's ``camera``.

    Late frames (latency). Measurements are processed in the order of their times
    (capture time for :meth:`add_frame`, tick time for :meth:`add_frames_at_tick`). One
    that arrives after the filter has moved past its time (a later frame of another
    camera was processed, or :meth:`predict_to` went to the current control tick) is
    handled exactly: the filter rolls back to the estimate after the last measurement
    before it, processes it and every later measurement again in time order (each gate
    decision made anew), and predicts to the time it was at. The result equals processing
    all measurements in time order (to rounding: Phi, Gamma and R1 of the ballistic model
    compose exactly over split intervals). The filter keeps every measurement whose time
    is at most ``history_s`` before the newest one, with the estimate after each (a few
    kB per frame); a measurement older than the oldest kept estimate raises ``ValueError``
    (:attr:`earliest_late_time_s` says how far back is allowed). ``late_count`` counts
    late measurements, ``refiltered_count`` the measurements processed again for them.
    :meth:`restart` starts the estimate over (``restart_count``).
    To read the estimate at a control tick while frames may still arrive late, use
    :meth:`predicted`, which does not move the filter.
    """

    def __init__(
        self,
        x0: np.ndarray,
        P0: np.ndarray,
        pixel_std_px: float = 0.5,
        gate_p: float | None = DEFAULT_GATE_P,
        accel_noise_std: float = 0.5,
        time_s: float = 0.0,
        history_s: float = DEFAULT_HISTORY_S,
        calibration: CalibrationConsider | None = None,
    ) -> None:
        if not (np.isfinite(pixel_std_px) and pixel_std_px > 0.0):
            raise ValueError(f"ViewlineKalmanFilter: pixel_std_px = {pixel_std_px!r}, must be > 0")
        self.calibration = calibration if calibration is not None and calibration.active else None
        if not (np.isfinite(history_s) and history_s >= 0.0):
            raise ValueError(f"ViewlineKalmanFilter: history_s = {history_s!r}, must be >= 0")
        self.model = BallisticModel(accel_noise_std)
        self.pixel_std_px = float(pixel_std_px)
        self.history_s = float(history_s)
        gate = None if gate_p is None else PSigmaGate(gate_p)
        x0, P0 = self._checked_prior(x0, P0, "ViewlineKalmanFilter")
        self.kf = KalmanFilter(x0, P0, gate)
        self.time_s = float(time_s)
        self.late_count = 0
        self.refiltered_count = 0
        self.restart_count = 0
        # The estimate before the oldest kept entry (initially the initial state), and
        # the kept entries in time order.
        self._anchor = self._checkpoint()
        self._entries: list[_Entry] = []

    # ------------------------------------------------------------------ state

    @property
    def x(self) -> np.ndarray:
        """The ball's estimate (6,) at ``time_s`` (``kf.x`` itself without consider
        parameters)."""
        return self.kf.x if self.calibration is None else self.kf.x[:6]

    @property
    def P(self) -> np.ndarray:
        """Its covariance (6, 6), the calibration offsets' effect included (``kf.P``
        itself without consider parameters)."""
        return self.kf.P if self.calibration is None else self.kf.P[:6, :6]

    def _checked_prior(self, x0, P0, owner: str) -> tuple[np.ndarray, np.ndarray]:
        """(x0, P0) of the ball (6,), (6, 6), augmented by the consider parameters."""
        x0 = np.array(x0, dtype=float).reshape(-1)
        P0 = np.array(P0, dtype=float)
        if x0.shape != (6,) or P0.shape != (6, 6):
            raise ValueError(f"{owner}: x0 {x0.shape}, P0 {P0.shape}; expected (6,), (6, 6)")
        if self.calibration is None:
            return x0, P0
        return self.calibration.augmented(x0, P0)

    def _matrices(self, dt_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(Phi, Gamma, R1) over ``dt_s`` of the filter's state (augmented if it is)."""
        Phi, Gamma, Q = self.model.matrices(dt_s)
        if self.calibration is None:
            return Phi, Gamma, Q
        Phi, Q, Gamma_aug = self.calibration.transition(Phi, Q, Gamma)
        assert Gamma_aug is not None
        return Phi, Gamma_aug, Q

    @property
    def accepted_count(self) -> int:
        return self.kf.accepted_count

    @property
    def rejected_count(self) -> int:
        return self.kf.rejected_count

    @property
    def earliest_late_time_s(self) -> float:
        """The earliest measurement time the filter can still take (s): the time of the
        oldest estimate it keeps. At least ``history_s`` before the newest measurement."""
        return self._anchor.time_s

    @property
    def _latest(self) -> _Checkpoint:
        """The estimate right after the newest measurement (or the anchor)."""
        return self._entries[-1].after if self._entries else self._anchor

    def _checkpoint(self) -> _Checkpoint:
        kf = self.kf
        return _Checkpoint(self.time_s, kf.x, kf.P, kf.accepted_count, kf.rejected_count)

    def _restore(self, c: _Checkpoint) -> None:
        # KalmanFilter assigns fresh arrays at every step, so the checkpoint's stay intact.
        kf = self.kf
        kf.x, kf.P = c.x, c.P
        kf.accepted_count, kf.rejected_count = c.accepted, c.rejected
        self.time_s = c.time_s

    def predicted(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """The estimate (x, P) predicted to ``t_s`` by (1) with the exact Phi, Gamma, R1
        (19)-(20), without changing the filter. ``t_s`` may lie anywhere from the newest
        measurement's time on (also before ``time_s``: no measurement lies in between);
        earlier raises ``ValueError``. For a controller reading the estimate at each tick
        while frames may still arrive late."""
        t_s = float(t_s)
        base = self._latest
        dt_s = t_s - base.time_s
        if dt_s < 0.0:
            raise ValueError(
                f"ViewlineKalmanFilter.predicted: {t_s!r} s is before the newest "
                f"measurement, at {base.time_s!r} s (only predictions forward from it)"
            )
        x, P = base.x[:6], base.P[:6, :6]  # the ball's part (the offsets are constant)
        if dt_s == 0.0:
            return x.copy(), P.copy()
        Phi, Gamma, Q = self.model.matrices(dt_s)
        P = Phi @ P @ Phi.T + Q  # (1): Phi P Phi^T + R1
        return Phi @ x + Gamma @ self.model.u, 0.5 * (P + P.T)

    def predict_to(self, t_s: float) -> None:
        """Time update (1) to ``t_s`` with the exact Phi, Gamma, R1 of the interval
        (19)-(20); a zero interval changes nothing. ``t_s`` before ``time_s``: ValueError
        (see :meth:`predicted` for an estimate at any time from the newest measurement)."""
        t_s = float(t_s)
        dt_s = t_s - self.time_s
        if dt_s < 0.0:
            raise ValueError(
                f"ViewlineKalmanFilter.predict_to: {t_s!r} s is before the estimate's time "
                f"{self.time_s!r} s (the filter only predicts forward)"
            )
        if dt_s == 0.0:
            return
        Phi, Gamma, Q = self._matrices(dt_s)
        self.kf.predict(Phi, Q, Gamma, self.model.u)  # (1), u = 1 (20)
        self.time_s = t_s

    def restart(self, x0: np.ndarray, P0: np.ndarray, time_s: float, since_s: float) -> int:
        """Start the estimate over from (``x0``, ``P0``) at ``time_s`` and filter again, in
        time order and each gate decision made anew, the kept measurements from
        ``since_s`` on (``time_s`` <= ``since_s``); older ones are forgotten (late frames
        are then taken back to ``time_s``). The counters are those before the first
        measurement filtered again plus its new decisions (as for a late frame), so
        ``accepted_count + rejected_count`` still counts each detection once;
        ``restart_count`` counts the restarts. Returns how many measurements were filtered
        again. For an observer whose estimate was lost (see
        :class:`~observer_gym.estimation.ball_catcher.observer.BallCatcherObserver`)."""
        x0, P0 = self._checked_prior(x0, P0, "ViewlineKalmanFilter.restart")
        time_s, since_s = float(time_s), float(since_s)
        if not time_s <= since_s:
            raise ValueError(
                f"ViewlineKalmanFilter.restart: time_s = {time_s!r} is after since_s = {since_s!r}"
            )
        resume_s = self.time_s
        i = bisect.bisect_left([e.time_s for e in self._entries], since_s)
        before = self._entries[i - 1].after if i > 0 else self._anchor
        again = self._entries[i:]
        kf = self.kf
        kf.x, kf.P = x0, 0.5 * (P0 + P0.T)
        kf.accepted_count, kf.rejected_count = before.accepted, before.rejected
        self.time_s = time_s
        self._anchor = self._checkpoint()
        self._entries = []
        self.restart_count += 1
        for entry in again:
            self._add(entry.time_s, entry.frames, entry.stacked, entry.camera, entry.position)
        self.predict_to(max(resume_s, self.time_s))
        return len(again)

    # ------------------------------------------------------------------ measurements

    def add_frame(
        self,
        capture_time_s: float,
        K: np.ndarray,
        T_world_cam: np.ndarray,
        uv_px: np.ndarray | None,
        camera: int = 0,
    ) -> UpdateResult:
        """Predict exactly to the frame's capture time, then update with its two rows
        (21)-(22), R2 = diag(std^2) at the predicted position; gated (27)-(30). A frame
        captured before ``time_s`` is a late frame (see the class docstring). ``camera``:
        the frame's camera (0 .. cameras - 1), whose calibration offset the rows carry
        when the filter has ``calibration``.

        ``uv_px`` None (no detection): prediction only, a missed measurement (a late one
        changes nothing).
        """
        t_s = float(capture_time_s)
        if uv_px is None:
            if t_s >= self.time_s:
                self.predict_to(t_s)
            else:
                self._check_within_history(t_s, "frame captured")
            return self.kf.update(None, np.empty((0, 6)), np.empty((0, 0)))
        frame = CameraFrame(t_s, K, T_world_cam, np.asarray(uv_px, dtype=float))
        return self._add(t_s, (frame,), stacked=False, camera=camera)

    def add_position(self, time_s: float, position_m: np.ndarray, R_m2: np.ndarray) -> UpdateResult:
        """Predict exactly to ``time_s``, then update with a measured ball position:

            y = H x + e,   H = [I_3 0_3] (the position part of the state),   E[e e^T] = R

        ``position_m`` (3,) in m, ``R_m2`` (3, 3) in m^2, symmetric positive definite;
        gated (27)-(30) like a frame. Not the paper's: its filter measures viewlines only;
        this is the smallest model for a measurement that is already a 3-D point (the
        ``learned-kf`` observer's network). A time before ``time_s`` is late and handled
        like a late frame. With ``calibration`` the consider parameters get no gain from
        it (H has zeros there: a position says nothing of the cameras' offsets)."""
        y = np.array(position_m, dtype=float).reshape(-1)
        R = np.array(R_m2, dtype=float)
        if (
            y.shape != (3,)
            or R.shape != (3, 3)
            or not (np.all(np.isfinite(y)) and np.all(np.isfinite(R)))
        ):
            raise ValueError(
                f"ViewlineKalmanFilter.add_position: position {y.shape} and R {R.shape} must "
                "be finite, (3,) and (3, 3)"
            )
        return self._add(float(time_s), (), stacked=False, position=_Position(y, 0.5 * (R + R.T)))

    def add_frames_at_tick(self, tick_time_s: float, frames: Sequence[CameraFrame]) -> UpdateResult:
        """The paper's timing: predict to ``tick_time_s``, stack the rows of all frames of
        the interval with time offsets dt = capture time - tick (23)-(26), update once.

        Beyond the paper's (26): the measured value is corrected for gravity over dt,
        y = -pi4 + pi3 g dt^2 / 2, which makes the row exact for the ballistic model
        (x(t + dt) = Phi(dt) x(t) + Gamma(dt)); the velocity term is the paper's. Process
        noise over dt is neglected (R1 over 20 ms is tiny next to R2). The whole stack is
        gated as one measurement, so one outlier rejects the tick's frames. Frames without
        a detection are skipped; none at all: prediction only. A tick before ``time_s`` is
        late and handled like a late frame (see the class docstring). Not with
        ``calibration`` (the stacked frames carry no camera): ``ValueError``.
        """
        if self.calibration is not None:
            raise ValueError(
                "ViewlineKalmanFilter.add_frames_at_tick: not with calibration consider "
                "parameters (use add_frame with each frame's camera)"
            )
        t_s = float(tick_time_s)
        detected = tuple(f for f in frames if f.uv_px is not None)
        if not detected:
            if t_s >= self.time_s:
                self.predict_to(t_s)
            else:
                self._check_within_history(t_s, "tick")
            return self.kf.update(None, np.empty((0, 6)), np.empty((0, 0)))
        return self._add(t_s, detected, stacked=True)

    def _add(
        self,
        t_s: float,
        frames: tuple[CameraFrame, ...],
        stacked: bool,
        camera: int = 0,
        position: _Position | None = None,
    ) -> UpdateResult:
        if t_s >= self.time_s:  # in order: the usual step
            result = self._apply(t_s, frames, stacked, camera, position)
            after = self._checkpoint()
            self._entries.append(_Entry(t_s, frames, stacked, after, camera, position))
            self._forget_old()
            return result
        self._check_within_history(t_s, "tick" if stacked else "frame captured")
        return self._refilter(_Entry(t_s, frames, stacked, self._anchor, camera, position))

    def _check_within_history(self, t_s: float, what: str) -> None:
        if t_s < self._anchor.time_s:
            newest = self._latest.time_s
            raise ValueError(
                f"ViewlineKalmanFilter: {what} at {t_s!r} s is older than the filter keeps: "
                f"late measurements are taken back to {self._anchor.time_s!r} s (history_s "
                f"= {self.history_s!r} s before the newest measurement, at {newest!r} s; "
                "the initial time at the earliest)"
            )

    def _refilter(self, late: _Entry) -> UpdateResult:
        """Insert ``late`` after every kept entry with a time <= its own, restart from the
        estimate before it, process it and all later entries, predict back to time_s."""
        resume_s = self.time_s
        times = [e.time_s for e in self._entries]
        i = bisect.bisect_right(times, late.time_s)
        self._restore(self._entries[i - 1].after if i > 0 else self._anchor)
        self._entries.insert(i, late)
        result = None
        for entry in self._entries[i:]:
            r = self._apply(entry.time_s, entry.frames, entry.stacked, entry.camera, entry.position)
            entry.after = self._checkpoint()
            if entry is late:
                result = r
        self.predict_to(resume_s)
        self.late_count += 1
        self.refiltered_count += len(self._entries) - i - 1
        self._forget_old()
        if result is None:  # late is among the entries processed: a bug otherwise
            raise RuntimeError("ViewlineKalmanFilter: the late measurement was not processed")
        return result

    def _forget_old(self) -> None:
        """Drop entries more than history_s older than the newest; the estimate after the
        last one dropped becomes the anchor."""
        horizon_s = self._entries[-1].time_s - self.history_s
        n_old = 0
        while n_old < len(self._entries) and self._entries[n_old].time_s < horizon_s:
            n_old += 1
        if n_old:
            self._anchor = self._entries[n_old - 1].after
            del self._entries[:n_old]

    def _depth_var_m2(self, T_world_cam: np.ndarray) -> float:
        """Variance of the estimated position's depth along the camera's optical axis."""
        axis = np.asarray(T_world_cam, dtype=float)[:3, 2]
        return float(axis @ self.kf.P[:3, :3] @ axis)

    def _apply(
        self,
        t_s: float,
        frames: tuple[CameraFrame, ...],
        stacked: bool,
        camera: int = 0,
        position: _Position | None = None,
    ) -> UpdateResult:
        """Predict to ``t_s`` and update with ``frames`` (all with a detection) or the
        measured ``position``."""
        self.predict_to(t_s)
        if position is not None:
            H = np.zeros((3, len(self.kf.x)))
            H[:, :3] = np.eye(3)  # y = [I 0] x + e
            result = self.kf.update(position.y_m, H, position.R_m2)
            if self.calibration is not None:
                self.kf.x, self.kf.P = self.calibration.reset_consider(self.kf.x, self.kf.P)
            return result
        if not stacked:
            (frame,) = frames
            uv_px = _detected(frame)
            C, y = viewline_rows(projection_matrix(frame.K, frame.T_world_cam), uv_px)
            std_m = viewline_noise_std(  # R2 from pixel noise and predicted depth
                frame.K,
                frame.T_world_cam,
                uv_px,
                self.kf.x[:3],
                self.pixel_std_px,
                depth_var_m2=self._depth_var_m2(frame.T_world_cam),
            )
            calibration = self.calibration
            if calibration is None:
                return self.kf.update(y, C, np.diag(std_m**2))  # (5)-(7), gated (27)-(30)
            position_m = self.kf.x[:3].copy()

            def residual_m(K: np.ndarray, T_world_cam: np.ndarray) -> np.ndarray:
                # the rows' residual C p - y through a camera (K, T_world_cam), p predicted
                C_c, y_c = viewline_rows(projection_matrix(K, T_world_cam), uv_px)
                return C_c[:, :3] @ position_m - y_c

            # y = C x + J c_camera + e (calibration_consider), gated with that S
            J = calibration.jacobian(residual_m, frame.K, frame.T_world_cam)
            result = self.kf.update(y, calibration.rows(C, J, camera), np.diag(std_m**2))
            self.kf.x, self.kf.P = calibration.reset_consider(self.kf.x, self.kf.P)
            return result
        g = self.model.gravity_mps2
        rows, values, variances = [], [], []
        for frame in frames:
            dt_s = float(frame.capture_time_s) - t_s
            uv = np.asarray(_detected(frame), dtype=float)
            C, y = viewline_rows(projection_matrix(frame.K, frame.T_world_cam), uv, dt_s)  # (26)
            y = y + C[:, 2] * (0.5 * g * dt_s * dt_s)  # gravity over dt (not in the paper)
            pos_at_capture = self.kf.x[:3] + dt_s * self.kf.x[3:]
            pos_at_capture[2] -= 0.5 * g * dt_s * dt_s
            std_m = viewline_noise_std(
                frame.K,
                frame.T_world_cam,
                uv,
                pos_at_capture,
                self.pixel_std_px,
                depth_var_m2=self._depth_var_m2(frame.T_world_cam),
            )
            rows.append(C)
            values.append(y)
            variances.append(std_m**2)
        C_all = np.vstack(rows)  # (23)
        y_all = np.concatenate(values)  # (24)
        return self.kf.update(y_all, C_all, np.diag(np.concatenate(variances)))
