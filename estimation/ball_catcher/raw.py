"""BallCatcher's ``raw`` observer: the detector and a triangulation alone, no filter.

The honest "no observer" baseline. Each camera's newest detection (by capture time; a
frame delivered late does not replace a newer one) is kept. When a step brings a newer
detection, the newest detection of all is paired with the other camera's newest detection
closest to it in capture time, and if the two were captured at most ``max_pair_gap_s``
apart (default one frame period) and are not the pair used last, the ball's position is
triangulated from them: the point nearest, in weighted least squares, to the four
viewline planes of the two pixels (:func:`triangulate`). The cameras are not synchronised
(the default "alternating" preset captures them 10 ms apart), and nothing corrects for
the ball's motion between the two captures: that error, a few centimetres at 6 m/s, is
part of what this baseline shows. The triangulated point is dated at the mean of the two
capture times.

Reported at each step: the last triangulated position, held through steps without a new
one (not predicted to the step's time: no model), and the velocity from finite
differences of the last two triangulated positions over their dates. Before the first
triangulation (e.g. with one camera only, ``camera_preset="single"``, which never
triangulates) the viewline filter's prior is reported
(:func:`~observer_gym.estimation.ball_catcher.observer.initial_estimate`), and before the
second its velocity. The box part is the robot's kinematics, as for every observer.

Covariance: the triangulation's, (A^T W A)^-1 with A the planes' normals and W their
inverse variances from the pixel noise
(:func:`~observer_gym.estimation.viewline.viewline_noise_std`), which ignores the cameras'
asynchrony and the hold (measured with alternating cameras: position error 36 mm along
the flight against a reported 4 mm); the velocity's that of the difference of two
independent triangulations divided by the time between them; held, not grown, between
triangulations; the prior's before. No innovation, so no NIS.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from observer_gym.envs.ball_catcher import BallCatcherEnv
from observer_gym.envs.ball_catcher.layout import (
    BALL_POS,
    BALL_VEL,
)
from observer_gym.estimation.ball_catcher.detector import BallCatcherDetector
from observer_gym.estimation.ball_catcher.frames import FrameReader
from observer_gym.estimation.ball_catcher.observer import (
    calibration_pixel_var_px2,
    default_pixel_std_px,
    initial_estimate,
)
from observer_gym.estimation.ball_catcher.state_layout import state_estimate
from observer_gym.estimation.camera_geometry import projection_matrix
from observer_gym.estimation.observer import Estimate
from observer_gym.estimation.viewline import CameraFrame, viewline_noise_std, viewline_rows

__all__ = ["RawObserver", "triangulate"]

MAX_CONDITION = 1e8  # normal matrices worse than this (near-parallel viewlines): no point


def triangulate(
    frames: tuple[CameraFrame, CameraFrame], pixel_std_px: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """(position (3,), covariance (3, 3)) of the world point nearest to the viewlines of
    two (or more) detections, or None for near-parallel viewlines.

    Each pixel gives two planes n_i . p = y_i (:func:`viewline_rows`, n_i unit, so
    n_i . p - y_i is a distance in m). The unweighted least-squares point p0 sets each
    row's std s_i (:func:`viewline_noise_std` at p0), then

        p = (A^T W A)^-1 A^T W y,   W = diag(1 / s_i^2),   Cov(p) = (A^T W A)^-1
    """
    pixels = [f.uv_px for f in frames if f.uv_px is not None]
    if len(pixels) != len(frames):
        raise ValueError("triangulate takes detections: a frame has no uv_px")
    rows, values = [], []
    for f, uv in zip(frames, pixels, strict=True):
        C, y = viewline_rows(projection_matrix(f.K, f.T_world_cam), uv)
        rows.append(C[:, :3])
        values.append(y)
    A, y = np.vstack(rows), np.concatenate(values)
    normal = A.T @ A
    if np.linalg.cond(normal) > MAX_CONDITION:
        return None
    p0 = np.linalg.solve(normal, A.T @ y)
    stds = np.concatenate(
        [
            viewline_noise_std(f.K, f.T_world_cam, uv, p0, pixel_std_px)
            for f, uv in zip(frames, pixels, strict=True)
        ]
    )
    w = 1.0 / stds**2
    # A^T W A and A^T W y
    information = (A.T * w) @ A
    covariance = np.linalg.inv(information)
    position = covariance @ ((A.T * w) @ y)
    return position, 0.5 * (covariance + covariance.T)


class RawObserver:
    """The ``raw`` observer of BallCatcher-v1 (see the module docstring).

    Args:
        env: the (unwrapped) BallCatcher env, made with obs_mode "rgb" or "measurements".
        pixel_std_px: the pixel noise for the triangulation's weights and covariance
            (default: the declared pixel noise with the calibration uncertainty as pixel
            variance, :func:`~observer_gym.estimation.ball_catcher.observer.
            calibration_pixel_var_px2`).
        max_pair_gap_s: the largest capture-time difference of two detections triangulated
            together (default: one frame period, 1 / ``frame_rate_hz``).
        detector: the rgb detector (default :class:`BallCatcherDetector`).
    """

    def __init__(
        self,
        env: BallCatcherEnv,
        pixel_std_px: float | None = None,
        max_pair_gap_s: float | None = None,
        detector: BallCatcherDetector | None = None,
    ) -> None:
        if not isinstance(env, BallCatcherEnv):
            raise ValueError(f"RawObserver needs a BallCatcherEnv, got {type(env).__name__}")
        cfg = env.config
        self.pixels = FrameReader(cfg, detector, owner="RawObserver")
        # the declared pixel noise and the calibration uncertainty as pixel variance
        declared_px2 = default_pixel_std_px(env) ** 2 + calibration_pixel_var_px2(env)
        self.pixel_std_px = float(math.sqrt(declared_px2) if pixel_std_px is None else pixel_std_px)
        if not (np.isfinite(self.pixel_std_px) and self.pixel_std_px > 0.0):
            raise ValueError(f"RawObserver: pixel_std_px = {pixel_std_px!r}, must be > 0")
        gap_s = 1.0 / cfg.frame_rate_hz + 0.5 * cfg.physics_dt_s
        self.max_pair_gap_s = float(gap_s if max_pair_gap_s is None else max_pair_gap_s)
        if not self.max_pair_gap_s >= 0.0:
            raise ValueError(f"RawObserver: max_pair_gap_s = {max_pair_gap_s!r}, must be >= 0")
        self.x0, self.P0 = initial_estimate(cfg)
        self.reset()

    def reset(self) -> None:
        self._newest: dict[Any, CameraFrame] = {}  # camera -> its newest detection
        self._pair: tuple | None = None  # (camera, capture time) of both, last triangulated
        self._last: tuple[float, np.ndarray, np.ndarray] | None = None  # date, position, cov
        self.x, self.P = self.x0.copy(), self.P0.copy()
        self.triangulations = 0

    def observe(self, obs: Any, info: dict, action: np.ndarray | None) -> Estimate:
        reports, newer = [], False
        for frame in info["frames"]:
            uv = self.pixels.detect(frame)
            camera = frame["camera_id"]
            reports.append({"camera_id": camera, "uv_px": uv})
            if uv is None:
                continue
            t_s = float(frame["capture_time_s"])
            kept = self._newest.get(camera)
            if kept is None or t_s > kept.capture_time_s:
                self._newest[camera] = CameraFrame(t_s, frame["K"], frame["T_world_cam"], uv)
                newer = True
        used = newer and self._triangulate_newest()
        mean, covariance = state_estimate(self.x, self.P, info)
        return Estimate(
            mean=mean,
            covariance=covariance,
            measurement_used=used,
            measurement=reports or None,
            time_s=float(info["time_s"]),
        )

    def _triangulate_newest(self) -> bool:
        """Triangulate the newest detection with its closest partner; whether a new
        position came out."""
        newest = self._newest
        anchor = max(newest, key=lambda c: newest[c].capture_time_s)
        t_anchor = newest[anchor].capture_time_s
        others = [c for c in newest if c != anchor]
        if not others:
            return False
        partner = min(others, key=lambda c: abs(newest[c].capture_time_s - t_anchor))
        t_partner = newest[partner].capture_time_s
        pair = (anchor, t_anchor, partner, t_partner)
        if abs(t_anchor - t_partner) > self.max_pair_gap_s or pair == self._pair:
            return False
        found = triangulate((newest[anchor], newest[partner]), self.pixel_std_px)
        if found is None:
            return False
        position, cov = found
        date_s = 0.5 * (t_anchor + t_partner)
        self._pair = pair
        self.triangulations += 1
        x, P = self.x.copy(), self.P.copy()
        x[:3] = position
        P[BALL_POS, BALL_POS] = cov
        if self._last is not None and date_s > self._last[0]:
            last_s, last_pos, last_cov = self._last
            dt_s = date_s - last_s
            # v = (p_k - p_{k-1}) / dt
            x[3:] = (position - last_pos) / dt_s
            # Cov(v) = (P_k + P_{k-1}) / dt^2,  Cov(p_k, v) = P_k / dt
            P[BALL_VEL, BALL_VEL] = (cov + last_cov) / dt_s**2
            P[BALL_POS, BALL_VEL] = cov / dt_s
            P[BALL_VEL, BALL_POS] = cov.T / dt_s
        else:  # no velocity from this one: the position's covariance is not correlated
            P[BALL_POS, BALL_VEL] = 0.0
            P[BALL_VEL, BALL_POS] = 0.0
        self._last = (date_s, position, cov)
        self.x, self.P = x, P
        return True
