"""PointMass-v0's observer: the red sphere's pixel (detected by colour, or read from the
measurements) back-projected onto the plane z = 0, and a constant-acceleration Kalman
filter driven by the commanded acceleration."""

from __future__ import annotations

from typing import Any

import numpy as np

from observer_gym.estimation.observer import Estimate, checked_measurement, checked_rgb_frame

DETECTOR_STD_PX = 0.5  # the colour centroid's error at 80 x 60 (one pixel's quantisation)


def red_centroid_px(frame: np.ndarray) -> np.ndarray | None:
    """The centroid (u, v) of the red pixels, or None if there are fewer than 2."""
    rgb = frame.astype(np.int16)
    mask = (rgb[..., 0] > 150) & (rgb[..., 1] < 80) & (rgb[..., 2] < 80)
    v, u = np.nonzero(mask)
    if len(u) < 2:
        return None
    return np.array([u.mean(), v.mean()])


def on_plane_m(
    uv_px: np.ndarray, K: np.ndarray, T_world_cam: np.ndarray
) -> tuple[np.ndarray, float]:
    """The point of the plane z = 0 seen at pixel ``uv_px``, and its depth (m)."""
    ray_cam = np.linalg.solve(K, np.array([uv_px[0], uv_px[1], 1.0]))
    ray_world = T_world_cam[:3, :3] @ ray_cam
    origin = T_world_cam[:3, 3]
    scale = -origin[2] / ray_world[2]
    return (origin + scale * ray_world)[:2], float(scale * ray_cam[2])


class PointMassKF:
    """Kalman filter on (x, y, vx, vy) with the commanded acceleration as input."""

    def __init__(self, env: Any) -> None:
        self.env = env
        self.dt_s = env.dt_s
        self.obs_mode = env.config.obs_mode
        spec = env.config
        self.pixel_std = float(np.hypot(DETECTOR_STD_PX, spec.measurement_noise_px))
        # velocity kicks as white noise: rate * E[kick^2] / 2 per axis, plus a floor
        kick_var = spec.push_rate_hz * spec.push_speed_mps**2 / 4
        self.q_vel = kick_var * self.dt_s + 1e-6
        self.reset()

    def reset(self) -> None:
        self.mean = np.zeros(4)
        self.cov = np.diag([1.0, 1.0, 0.1, 0.1])
        self.started = False

    def _pixel(self, obs: Any) -> np.ndarray | None:
        """The detection in ``obs``, None for none (ValueError for a malformed ``obs``)."""
        if self.obs_mode == "measurements":
            checked = checked_measurement("kf", obs, self.env.observation_space)
            pixel = checked["ball_px"]
            return pixel if checked["detected"][0] == 1 and np.all(np.isfinite(pixel)) else None
        return red_centroid_px(checked_rgb_frame(obs, self.env.rig.image_size_px, "kf"))

    def observe(self, obs: Any, info: dict, action: np.ndarray | None) -> Estimate:
        dt = self.dt_s
        frames = info["frames"]
        pixel = self._pixel(obs) if frames else None  # checked before anything changes
        if action is not None:
            F = np.eye(4)
            F[0, 2] = F[1, 3] = dt
            G = np.vstack([0.5 * dt * dt * np.eye(2), dt * np.eye(2)])
            # x' = F x + G a; P' = F P F^T + Q
            self.mean = F @ self.mean + G @ np.asarray(action, float)
            self.cov = F @ self.cov @ F.T + np.diag([0.0, 0.0, self.q_vel, self.q_vel])
        used, nis, measurement = False, None, None
        if pixel is not None:
            frame = frames[-1]
            z, depth_m = on_plane_m(pixel, frame["K"], frame["T_world_cam"])
            measurement = z
            r = (self.pixel_std * depth_m / frame["K"][0, 0]) ** 2
            if not self.started:
                self.mean = np.array([z[0], z[1], 0.0, 0.0])
                self.cov = np.diag([r, r, 0.01, 0.01])
                self.started = True
            else:
                H = np.hstack([np.eye(2), np.zeros((2, 2))])
                # S = H P H^T + R; K = P H^T S^-1
                S = H @ self.cov @ H.T + r * np.eye(2)
                gain = self.cov @ H.T @ np.linalg.inv(S)
                d = z - H @ self.mean
                nis = float(d @ np.linalg.solve(S, d))
                self.mean = self.mean + gain @ d
                self.cov = (np.eye(4) - gain @ H) @ self.cov
                self.cov = 0.5 * (self.cov + self.cov.T)
            used = True
        return Estimate(
            self.mean.copy(),
            self.cov.copy(),
            used,
            measurement,
            float(info["time_s"]),
            nis,
            2 if nis is not None else 0,
        )


OBSERVERS = {"kf": PointMassKF}
