"""What each delivered camera frame of an episode showed the observer, and where the
estimate and the truth fall in it: the data a video (:mod:`observer_gym.train.reports.video`)
or a recording draws.

:func:`delivered_frames` turns one step's ``info`` (and the env's newest delivered images)
into one :class:`DeliveredFrame` per frame in ``info["frames"]``: the camera id, the image,
the capture and delivery times, the nominal ``K`` and ``T_world_cam`` (what the observer
was told) and the true ones (what the world's camera was), the ground-truth state, the
estimate and its covariance, and the observer's detection. :func:`marker_pixels` projects
a state into an image: the tracked object's pixel (the ball of BallTable and BallCatcher,
the target of TargetFollower) and, for an estimate, its pixel covariance J P J^T through
the projection's Jacobian J (central differences of the projection: a few lines, and the
same for every system). Systems outside the package get no markers (None).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from observer_gym.envs import system_of
from observer_gym.envs.camera import project_points

# A state (n,) and a camera (K, T_world_cam) -> the tracked object's pixel (u, v), or None
# when it is behind the camera
Projection = Callable[[np.ndarray, np.ndarray, np.ndarray], "np.ndarray | None"]


@dataclasses.dataclass(frozen=True)
class DeliveredFrame:
    """One frame the observer received, with what the truth and the estimate were at the
    step it arrived. Times in seconds since the reset; ``K`` and ``T_world_cam`` are the
    nominal calibration the frame came with, ``K_true`` and ``T_world_cam_true`` the world's
    camera (they differ when the env sets a calibration error)."""

    step: int  # the env step that delivered it (0: the reset)
    camera_id: int
    image: np.ndarray | None  # (H, W, 3) uint8 RGB; None for a frame without pixels
    capture_time_s: float
    delivery_time_s: float
    K: np.ndarray
    T_world_cam: np.ndarray
    K_true: np.ndarray
    T_world_cam_true: np.ndarray
    state: np.ndarray  # the ground truth (the env's "state" layout)
    estimate: np.ndarray | None  # the observer's mean (same layout), None without one
    covariance: np.ndarray | None
    detection_px: np.ndarray | None  # the observer's detection in this camera, (u, v)

    @property
    def calibration_differs(self) -> bool:
        """Whether the world's camera is not the nominal one (a calibration error)."""
        return not (
            np.array_equal(self.K, self.K_true)
            and np.array_equal(self.T_world_cam, self.T_world_cam_true)
        )

    @property
    def age_ms(self) -> float:
        """Capture to delivery, in milliseconds."""
        return 1e3 * (self.delivery_time_s - self.capture_time_s)


def _ball_table_projection() -> Projection:
    from observer_gym.envs.ball_table import geometry as geo
    from observer_gym.estimation.ball_table.pixel_ekf import T_world_table

    def project(state: np.ndarray, K: np.ndarray, T_world_cam: np.ndarray) -> np.ndarray | None:
        # the ball's centre: (x, y, r) in the table frame at the state's tilt, table at home
        T = T_world_table(state[4:6])
        centre = T[:3, :3] @ np.array([state[0], state[1], geo.BALL_RADIUS_M]) + T[:3, 3]
        return _pinhole(K, T_world_cam, centre)

    return project


def _ball_catcher_projection() -> Projection:
    def project(state: np.ndarray, K: np.ndarray, T_world_cam: np.ndarray) -> np.ndarray | None:
        return _pinhole(K, T_world_cam, state[0:3])

    return project


def _target_follower_projection() -> Projection:
    def project(state: np.ndarray, K: np.ndarray, T_world_cam: np.ndarray) -> np.ndarray | None:
        # the image state (x_i right, y_i up from the principal point) is already pixels
        return np.array([state[0] + K[0, 2], K[1, 2] - state[1]])

    return project


def _pinhole(K: np.ndarray, T_world_cam: np.ndarray, point_world: np.ndarray) -> np.ndarray | None:
    uv, depth = project_points(K, T_world_cam, np.asarray(point_world, dtype=float)[None])
    return uv[0] if depth[0] > 1e-6 else None


_PROJECTIONS: dict[str, Callable[[], Projection]] = {
    "ball_table": _ball_table_projection,
    "ball_catcher": _ball_catcher_projection,
    "target_follower": _target_follower_projection,
}


def projection_for(env: Any) -> Projection | None:
    """The projection of ``env``'s system (its tracked object's pixel from a state), None
    for a system the package does not know."""
    make = _PROJECTIONS.get(system_of(env.unwrapped).name)
    return None if make is None else make()


@dataclasses.dataclass(frozen=True)
class MarkerPixel:
    """A state's tracked object in an image: its pixel and (for an estimate) the pixel
    covariance (2, 2) through the projection's Jacobian."""

    uv_px: np.ndarray
    covariance_px2: np.ndarray | None


def marker_pixels(
    projection: Projection,
    state: np.ndarray,
    K: np.ndarray,
    T_world_cam: np.ndarray,
    covariance: np.ndarray | None = None,
    step: float = 1e-6,
) -> MarkerPixel | None:
    """Where ``state`` puts the tracked object in the camera (K, T_world_cam), and with
    ``covariance`` (n, n) its pixel covariance J P J^T, J = d(u, v)/d(state) by central
    differences of ``step`` (relative to each entry's size); None if it is behind the
    camera."""
    state = np.asarray(state, dtype=float)
    uv = projection(state, K, T_world_cam)
    if uv is None or not np.all(np.isfinite(uv)):
        return None
    if covariance is None:
        return MarkerPixel(np.asarray(uv, dtype=float), None)
    J = np.zeros((2, state.size))
    for i in np.flatnonzero(np.diag(covariance) > 0):  # only the entries with uncertainty
        h = step * max(1.0, abs(state[i]))
        up, down = state.copy(), state.copy()
        up[i] += h
        down[i] -= h
        plus, minus = projection(up, K, T_world_cam), projection(down, K, T_world_cam)
        if plus is None or minus is None:
            return MarkerPixel(np.asarray(uv, dtype=float), None)
        J[:, i] = (plus - minus) / (2 * h)
    return MarkerPixel(np.asarray(uv, dtype=float), J @ covariance @ J.T)


def _detection_px(
    system: str, measurement: Any, camera_id: int, K: np.ndarray, T_world_cam: np.ndarray
) -> np.ndarray | None:
    """The observer's detection (its estimate's ``measurement``) as a pixel in camera
    ``camera_id``, for the package's systems; None when there is none."""
    if measurement is None:
        return None
    if system == "ball_table":
        if not getattr(measurement, "ball_found", False):
            return None
        T = np.asarray(measurement.T_world_table)
        x, y = np.asarray(measurement.ball_pos_table_m, dtype=float)
        centre = T[:3, :3] @ np.array([x, y, float(measurement.ball_radius_m)]) + T[:3, 3]
        return _pinhole(K, T_world_cam, centre)
    if system == "ball_catcher" and isinstance(measurement, list | tuple):
        for found in measurement:
            if isinstance(found, Mapping) and found.get("camera_id") == camera_id:
                return np.asarray(found["uv_px"], dtype=float)
        return None
    if system == "target_follower":
        values = np.asarray(measurement, dtype=float).reshape(-1)
        return np.array([values[0] + K[0, 2], K[1, 2] - values[1]]) if values.size >= 2 else None
    return None


def delivered_frames(env: Any, info: Mapping[str, Any], step: int) -> list[DeliveredFrame]:
    """The frames delivered at this step (``info`` of the reset or a step, as the observer
    wrapper returned it), one per entry of ``info["frames"]``, with the env's newest
    image of each camera (``env.unwrapped.rig.latest``; two frames of one camera arriving
    in the same step both show the newer image)."""
    base = env.unwrapped
    system = system_of(base).name
    estimate = info.get("estimate")
    state = np.array(info["state"], dtype=float)
    frames = []
    for nominal, truth in zip(info["frames"], info["truth"]["frames"], strict=True):
        camera_id = int(nominal["camera_id"])
        latest = base.rig.latest[camera_id]
        payload = None if latest is None else latest.payload
        image = payload if isinstance(payload, np.ndarray) and payload.ndim == 3 else None
        K, T = np.asarray(nominal["K"]), np.asarray(nominal["T_world_cam"])
        detection = (
            None
            if estimate is None
            else _detection_px(system, estimate.get("measurement"), camera_id, K, T)
        )
        frames.append(
            DeliveredFrame(
                step=step,
                camera_id=camera_id,
                image=image,
                capture_time_s=float(nominal["capture_time_s"]),
                delivery_time_s=float(nominal["delivery_time_s"]),
                K=K,
                T_world_cam=T,
                K_true=np.asarray(truth["K"]),
                T_world_cam_true=np.asarray(truth["T_world_cam"]),
                state=state,
                estimate=None if estimate is None else np.asarray(estimate["mean"], dtype=float),
                covariance=(
                    None if estimate is None else np.asarray(estimate["covariance"], dtype=float)
                ),
                detection_px=detection,
            )
        )
    return frames
