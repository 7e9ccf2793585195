"""The viewline Kalman filter: a flying ball tracked from unsynchronised camera frames.

spec/catcher.md (Linderoth et al., ICRA 2010): every detected image point gives two
linear constraints on the state, the two planes through the camera centre whose
intersection is the point's viewline (17)-(22); several frames of one control interval can
be stacked with time-offset rows (23)-(26); outliers are rejected by the p-sigma test
(27)-(30). The process model is :class:`~observer_gym.estimation.models.BallisticModel`
(world frame z up; the paper's has y up).

Beyond the paper: the filter predicts exactly (Phi, Gamma, R1 of the actual interval) to
each frame's capture time, so aperiodic frames need no offset rows (:meth:`add_frame`);
the paper's stacked form is :meth:`ViewlineKalmanFilter.add_frames_at_tick`. R2, which the
paper does not give, is derived from the pixel noise in :func:`viewline_noise_std`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from observer_gym.estimation.camera_geometry import projection_matrix, viewline_planes
from observer_gym.estimation.filters import KalmanFilter, PSigmaGate, UpdateResult
from observer_gym.estimation.models import BallisticModel

__all__ = [
    "DEFAULT_GATE_P",
    "MIN_DEPTH_M",
    "CameraFrame",
    "ViewlineKalmanFilter",
    "viewline_noise_std",
    "viewline_rows",
]

# p of the outlier test (30). For an isotropic 2x2 S, ||d||^2 / sigma^2 is chi-square with
# 2 degrees of freedom, so a good point is rejected with probability exp(-p^2 / 2): 0.22 %
# at p = 3.5 (one false rejection per ~450 frames, which costs only that frame), while a
# detection on the wrong object, tens of pixels off, is still far outside.
DEFAULT_GATE_P = 3.5

# Depths below this are clamped in viewline_noise_std: early on the predicted position can
# be at or behind a camera (the initial guess is metres off), where z_cam <= 0 would give a
# zero or negative std, i.e. a singular or indefinite R2. Then C P C^T, not R2, dominates S
# anyway, so any small positive floor is safe; 0.1 m is nearer than any ball a camera of
# the catcher rig can see sharply.
MIN_DEPTH_M = 0.1


def viewline_rows(
    P_cam: np.ndarray, uv_px: np.ndarray, time_offset_s: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """The two measurement rows of image point ``uv_px`` seen by camera matrix ``P_cam``.

    Planes pi = P_c^T l with l_x = (-1, 0, u), l_y = (0, -1, v) (17)-(18), normalised so
    that ||(pi1, pi2, pi3)|| = 1; row c = (pi1, pi2, pi3, dt pi1, dt pi2, dt pi3) with
    measured value -pi4 (21)-(22), (25)-(26), dt = ``time_offset_s`` (capture time minus
    the state's time). Returns (C (2, 6), y (2,)); C x - y is the signed distance (m) of
    the position p + dt v from each plane.
    """
    planes = viewline_planes(P_cam, uv_px)  # (17), (18), (21) normalisation
    C = np.empty((2, 6))
    C[:, :3] = planes[:, :3]  # (22)
    C[:, 3:] = time_offset_s * planes[:, :3]  # (26): x(t_k + dt) ~ x(t_k) + dt x'(t_k)
    return C, -planes[:, 3]  # (22), (26): measured value -pi4


def viewline_noise_std(
    K: np.ndarray,
    T_world_cam: np.ndarray,
    uv_px: np.ndarray,
    predicted_pos_world: np.ndarray,
    pixel_std_px: float,
    min_depth_m: float = MIN_DEPTH_M,
    depth_var_m2: float = 0.0,
) -> np.ndarray:
    """Std (m) of the two viewline rows' measured values for pixel noise ``pixel_std_px``.

    With P = K [R | t] (R, t world to camera; rows r1, r2, r3 of R) and zero skew,
    pi_x = P^T (-1, 0, u) has the normal n_x = -fx r1 + (u - cx) r3, of length
    sqrt(fx^2 + (u - cx)^2) (r1 is orthogonal to r3), and for a point X with camera
    coordinates (X_c, Y_c, Z_c):

        n_x . X + pi_x4 = -fx X_c - cx Z_c + u Z_c = Z_c (u - u(X)),   u(X) = fx X_c/Z_c + cx

    so after normalisation the row's residual is Z_c (u - u(X)) / ||n_x||: a pixel error
    delta in u moves it by delta Z_c / ||n_x||, and

        std_x = sigma_px Z_c / sqrt(fx^2 + (u - cx)^2)
        std_y = sigma_px Z_c / sqrt(fy^2 + (v - cy)^2)   (likewise, from pi_y)

    with Z_c the depth of the predicted position (clamped to ``min_depth_m``, see
    :data:`MIN_DEPTH_M`). ||n_x|| depends on u too, but it multiplies u - u(X), which is
    zero at the point's own pixel, so to first order in delta the change is
    delta Z_c / ||n_x|| (checked by finite differences in the tests).

    ``depth_var_m2``: the variance of Z_c under the current estimate (r3^T P_pos r3). With
    delta independent of Z_c, Var(delta Z_c) = sigma_px^2 E[Z_c^2] = sigma_px^2 (Z_c^2 +
    var), so the std uses sqrt(Z_c^2 + var) as the depth. Without it a poor estimate near
    a camera centre (through which every viewline plane passes, so it fits every frame)
    gets a tiny R2 and locks in there (seen with a single camera and a 70 m initial error).
    """
    K = np.asarray(K, dtype=float)
    T = np.asarray(T_world_cam, dtype=float)
    p_cam = (np.asarray(predicted_pos_world, dtype=float) - T[:3, 3]) @ T[:3, :3]
    z_cam = max(float(np.sqrt(max(p_cam[2], 0.0) ** 2 + depth_var_m2)), min_depth_m)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    u, v = float(uv_px[0]), float(uv_px[1])
    return pixel_std_px * z_cam / np.array([np.hypot(fx, u - cx), np.hypot(fy, v - cy)])


@dataclass(frozen=True, slots=True)
class CameraFrame:
    """One camera frame's detection: capture time (s), intrinsics K (3, 3), pose
    ``T_world_cam`` (4, 4, camera to world, OpenCV axes) and pixel ``uv_px`` (2,) or None
    when nothing was detected."""

    capture_time_s: float
    K: np.ndarray
    T_world_cam: np.ndarray
    uv_px: np.ndarray | None


class ViewlineKalmanFilter:
    """Kalman filter (filter form (5)-(7)) on :class:`BallisticModel` with viewline rows.

    ``x`` = (x, y, z, vx, vy, vz) (m, m/s, world frame, z up) and ``P`` are the estimate
    at ``time_s``. Frames must come in capture-time order; a frame captured before
    ``time_s`` raises ``ValueError`` (no rollback yet). Counts of used and gated-out
    detections: ``accepted_count``, ``rejected_count``.

    - ``pixel_std_px``: detector noise (px), mapped to R2 by :func:`viewline_noise_std`.
    - ``gate_p``: p of the outlier test (27)-(30), :data:`DEFAULT_GATE_P`; None: no gate.
    - ``accel_noise_std``: white acceleration noise of the model, m/s^2 per sqrt(s)
      (intensity m^2/s^3), see :class:`BallisticModel`.
    """

    def __init__(
        self,
        x0: np.ndarray,
        P0: np.ndarray,
        pixel_std_px: float = 0.5,
        gate_p: float | None = DEFAULT_GATE_P,
        accel_noise_std: float = 0.5,
        time_s: float = 0.0,
    ) -> None:
        if not (np.isfinite(pixel_std_px) and pixel_std_px > 0.0):
            raise ValueError(f"ViewlineKalmanFilter: pixel_std_px = {pixel_std_px!r}, must be > 0")
        self.model = BallisticModel(accel_noise_std)
        self.pixel_std_px = float(pixel_std_px)
        gate = None if gate_p is None else PSigmaGate(gate_p)
        self.kf = KalmanFilter(np.asarray(x0, dtype=float), np.asarray(P0, dtype=float), gate)
        if self.kf.dim_x != 6:
            raise ValueError(f"ViewlineKalmanFilter: state has {self.kf.dim_x} entries, not 6")
        self.time_s = float(time_s)

    @property
    def x(self) -> np.ndarray:
        return self.kf.x

    @property
    def P(self) -> np.ndarray:
        return self.kf.P

    @property
    def accepted_count(self) -> int:
        return self.kf.accepted_count

    @property
    def rejected_count(self) -> int:
        return self.kf.rejected_count

    def _check_not_late(self, t_s: float, what: str) -> None:
        if t_s < self.time_s:
            raise ValueError(
                f"ViewlineKalmanFilter: {what} at {t_s!r} s is before the estimate's time "
                f"{self.time_s!r} s (late frame; out-of-order handling not implemented)"
            )

    def _depth_var_m2(self, T_world_cam: np.ndarray) -> float:
        """Variance of the estimated position's depth along the camera's optical axis."""
        axis = np.asarray(T_world_cam, dtype=float)[:3, 2]
        return float(axis @ self.kf.P[:3, :3] @ axis)

    def predict_to(self, t_s: float) -> None:
        """Time update (1) to ``t_s`` with the exact Phi, Gamma, R1 of the interval
        (19)-(20); a zero interval changes nothing. ``t_s`` before ``time_s``: ValueError."""
        t_s = float(t_s)
        self._check_not_late(t_s, "predict_to")
        dt_s = t_s - self.time_s
        if dt_s == 0.0:
            return
        Phi, Gamma, Q = self.model.matrices(dt_s)
        self.kf.predict(Phi, Q, Gamma, self.model.u)  # (1), u = 1 (20)
        self.time_s = t_s

    def add_frame(
        self,
        capture_time_s: float,
        K: np.ndarray,
        T_world_cam: np.ndarray,
        uv_px: np.ndarray | None,
    ) -> UpdateResult:
        """Predict exactly to the frame's capture time, then update with its two rows
        (21)-(22), R2 = diag(std^2) at the predicted position; gated (27)-(30).

        ``uv_px`` None (no detection): prediction only, a missed measurement.
        """
        self._check_not_late(float(capture_time_s), "frame captured")
        self.predict_to(capture_time_s)
        if uv_px is None:
            return self.kf.update(None, np.empty((0, 6)), np.empty((0, 0)))
        uv = np.asarray(uv_px, dtype=float)
        C, y = viewline_rows(projection_matrix(K, T_world_cam), uv)  # (21)-(22)
        std_m = viewline_noise_std(
            K,
            T_world_cam,
            uv,
            self.kf.x[:3],
            self.pixel_std_px,
            depth_var_m2=self._depth_var_m2(T_world_cam),
        )
        return self.kf.update(y, C, np.diag(std_m**2))  # (5)-(7)

    def add_frames_at_tick(self, tick_time_s: float, frames: Sequence[CameraFrame]) -> UpdateResult:
        """The paper's timing: predict to ``tick_time_s``, stack the rows of all frames of
        the interval with time offsets dt = capture time - tick (23)-(26), update once.

        Beyond the paper's (26): the measured value is corrected for gravity over dt,
        y = -pi4 + pi3 g dt^2 / 2, which makes the row exact for the ballistic model
        (x(t + dt) = Phi(dt) x(t) + Gamma(dt)); the velocity term is the paper's. Process
        noise over dt is neglected (R1 over 20 ms is tiny next to R2). The whole stack is
        gated as one measurement, so one outlier rejects the tick's frames. Frames without
        a detection are skipped; none at all: prediction only.
        """
        self._check_not_late(float(tick_time_s), "tick")
        self.predict_to(tick_time_s)
        g = self.model.gravity_mps2
        rows, values, variances = [], [], []
        for frame in frames:
            if frame.uv_px is None:
                continue
            dt_s = float(frame.capture_time_s) - self.time_s
            uv = np.asarray(frame.uv_px, dtype=float)
            C, y = viewline_rows(projection_matrix(frame.K, frame.T_world_cam), uv, dt_s)
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
        if not rows:
            return self.kf.update(None, np.empty((0, 6)), np.empty((0, 0)))
        C_all = np.vstack(rows)  # (23)
        y_all = np.concatenate(values)  # (24)
        return self.kf.update(y_all, C_all, np.diag(np.concatenate(variances)))
