"""Camera geometry for observers: projection matrices, back-projected rays and viewline planes.

Conventions are those of :mod:`observer_gym.envs.camera` (OpenCV: camera x right, y down,
z forward; pixel (i, j) centred at (i, j); ``T_world_cam`` maps camera-frame points to the
world). Forward projection of points is :func:`observer_gym.envs.camera.project_points`;
this module adds the inverse direction and the viewline-plane form of a pixel measurement
used by the viewline Kalman filter (docs/spec/catcher.md, equations (12)-(22)).
"""

from __future__ import annotations

import numpy as np

from observer_gym.envs.camera import PinholeIntrinsics, project_points

__all__ = [
    "PinholeIntrinsics",
    "pixel_ray",
    "project_points",
    "projection_matrix",
    "ray_plane_intersection",
    "viewline_planes",
]


def projection_matrix(K: np.ndarray, T_world_cam: np.ndarray) -> np.ndarray:
    """The 3x4 camera matrix P = K [R^T | -R^T t] with x ~ P X (catcher spec (12)).

    R, t are the rotation and position of the camera in the world (``T_world_cam``), so
    [R^T | -R^T t] is ``T_cam_world`` without its last row.
    """
    R = np.asarray(T_world_cam, dtype=float)[:3, :3]
    t = np.asarray(T_world_cam, dtype=float)[:3, 3]
    return np.asarray(K, dtype=float) @ np.column_stack([R.T, -R.T @ t])


def pixel_ray(
    K: np.ndarray, T_world_cam: np.ndarray, uv: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Back-projection of pixel(s) ``uv`` ((2,) or (N, 2)) to rays in the world frame.

    Returns ``(origin_world, direction_world)``: the camera centre (3,) and unit
    direction(s) ((3,) or (N, 3)). The point at distance s along the ray, origin + s *
    direction, projects to ``uv`` for every s > 0. Written with the inverse of K in closed
    form (no distortion, zero skew), as envs.camera does.
    """
    uv = np.asarray(uv, dtype=float)
    K = np.asarray(K, dtype=float)
    x = (uv[..., 0] - K[0, 2]) / K[0, 0]
    y = (uv[..., 1] - K[1, 2]) / K[1, 1]
    ray_cam = np.stack([x, y, np.ones_like(x)], axis=-1)
    direction = ray_cam @ np.asarray(T_world_cam, dtype=float)[:3, :3].T
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    return np.array(T_world_cam, dtype=float)[:3, 3], direction


def viewline_planes(P: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """The two planes whose intersection is the viewline of pixel ``uv`` = (u, v).

    pi_x = P^T (-1, 0, u) and pi_y = P^T (0, -1, v) (catcher spec (17)-(18)), each scaled
    so that ||(pi1, pi2, pi3)|| = 1 (spec (21)-(22)). A world point X on the viewline
    satisfies pi[:3] . X = -pi[3] for both rows; for any X, pi[:3] . X + pi[3] is the
    signed distance (metres) from X to that plane. Returns a (2, 4) array.
    """
    u, v = float(uv[0]), float(uv[1])
    lines = np.array([[-1.0, 0.0, u], [0.0, -1.0, v]])
    planes = lines @ np.asarray(P, dtype=float)  # row i is (P^T l_i)^T
    return planes / np.linalg.norm(planes[:, :3], axis=1, keepdims=True)


def ray_plane_intersection(
    origin: np.ndarray,
    direction: np.ndarray,
    plane_point: np.ndarray,
    plane_normal: np.ndarray,
) -> np.ndarray | None:
    """The point where the ray origin + s * direction (s >= 0) meets a plane.

    Returns None when the ray is parallel to the plane (|n . d| < 1e-12) or the plane is
    behind the ray's origin (s < 0). Neither vector needs to be of unit length.
    """
    origin = np.asarray(origin, dtype=float)
    direction = np.asarray(direction, dtype=float)
    normal = np.asarray(plane_normal, dtype=float)
    denominator = float(normal @ direction)
    if abs(denominator) < 1e-12:
        return None
    s = float(normal @ (np.asarray(plane_point, dtype=float) - origin)) / denominator
    if s < 0.0:
        return None
    return origin + s * direction
