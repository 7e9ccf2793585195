"""Viewlines: an image point as two linear constraints on a point's position.

docs/spec/catcher.md (Linderoth et al., ICRA 2010): every detected image point gives two
linear constraints on the state, the two planes through the camera centre whose
intersection is the point's viewline (17)-(22); frames captured off the state's time get
time-offset rows (25)-(26). R2, which the paper does not give, is derived from the pixel
noise in :func:`viewline_noise_std`. The filter built on these rows, BallCatcher's, is
``observer_gym.estimation.ball_catcher.filters.ViewlineKalmanFilter``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from observer_gym.estimation.camera_geometry import viewline_planes

__all__ = ["MIN_DEPTH_M", "CameraFrame", "viewline_noise_std", "viewline_rows"]

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
