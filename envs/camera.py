"""Pinhole cameras: intrinsics, poses, projection and rendering.

Conventions (the OpenCV ones, used everywhere in observer-gym):

- Camera frame: x right, y down, z forward along the optical axis.
- Pixel coordinates (u, v): u to the right, v down, the centre of pixel (i, j) at (i, j).
- ``T_world_cam``: 4x4 homogeneous transform taking camera-frame points to the world.

PyBullet renders with OpenGL matrices; :func:`gl_view_matrix` and
:meth:`PinholeIntrinsics.gl_projection` build them from the calibration above so that a
rendered frame and :func:`project_points` agree to a fraction of a pixel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike

from observer_gym.envs.bullet import pybullet
from observer_gym.envs.sim import Simulation
from observer_gym.envs.transforms import pose_matrix


@dataclass(frozen=True)
class PinholeIntrinsics:
    """An undistorted pinhole camera."""

    width_px: int
    height_px: int
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float

    @classmethod
    def from_fov(cls, width_px: int, height_px: int, hfov_deg: float) -> PinholeIntrinsics:
        """Square pixels, principal point at the image centre, focal length from the
        horizontal field of view (320x240 at 90 deg gives fx = fy = 160, cx = 160, cy = 120,
        as in docs/spec/table_ball.md)."""
        if not 0.0 < hfov_deg < 180.0:
            raise ValueError(f"hfov_deg must be in (0, 180), got {hfov_deg}")
        f = (width_px / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
        return cls(width_px, height_px, f, f, width_px / 2.0, height_px / 2.0)

    @property
    def K(self) -> np.ndarray:
        """The 3x3 camera matrix."""
        return np.array(
            [[self.fx_px, 0.0, self.cx_px], [0.0, self.fy_px, self.cy_px], [0.0, 0.0, 1.0]]
        )

    def gl_projection(self, near_m: float, far_m: float) -> list[float]:
        """OpenGL projection matrix (column-major, as PyBullet wants it) for this K.

        TinyRenderer puts pixel column i's centre at window x = i, and (its rows being
        flipped) row j's centre at window y = height - 1 - j; the offsets below make a
        rendered point land on the pixel ``project_points`` gives, which
        tests/envs/test_ball_table_camera.py checks to a fraction of a pixel.
        """
        w, h = self.width_px, self.height_px
        m = np.zeros((4, 4))
        m[0, 0] = 2.0 * self.fx_px / w
        m[0, 2] = 1.0 - 2.0 * self.cx_px / w
        m[1, 1] = 2.0 * self.fy_px / h
        m[1, 2] = 2.0 * (self.cy_px + 1.0) / h - 1.0
        m[2, 2] = -(far_m + near_m) / (far_m - near_m)
        m[2, 3] = -2.0 * far_m * near_m / (far_m - near_m)
        m[3, 2] = -1.0
        return m.T.reshape(-1).tolist()


def look_at(eye_world: ArrayLike, target_world: ArrayLike, up_world=(0.0, 0.0, 1.0)):
    """``T_world_cam`` of a camera at ``eye_world`` whose optical axis points at
    ``target_world``, with image 'up' as close to ``up_world`` as possible."""
    eye = np.asarray(eye_world, dtype=float)
    z = np.asarray(target_world, dtype=float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up_world, dtype=float))  # image right = forward x up
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("look_at: the viewing direction is parallel to up_world")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return pose_matrix(np.column_stack([x, y, z]), eye)


def gl_view_matrix(T_world_cam: np.ndarray) -> list[float]:
    """OpenGL view matrix (column-major) of a camera with pose ``T_world_cam``.

    ``R_gl_world = diag(1, -1, -1) @ R_world_cam.T`` (OpenCV camera axes in OpenGL's: x
    right, y up, z backwards) is written out: every entry of that matrix product has one
    nonzero term, +-R[j, i], so the product is exactly it, except that its sum starts
    at +0.0 and so turns a -0.0 into +0.0, as ``+ 0.0`` does (the view matrix is
    NumPy's bit for bit: tests/envs/test_ball_table_camera.py)."""
    (r00, r01, r02, _), (r10, r11, r12, _), (r20, r21, r22, _), _ = T_world_cam.tolist()
    R_gl_world = [
        [r00 + 0.0, r10 + 0.0, r20 + 0.0],
        [-r01 + 0.0, -r11 + 0.0, -r21 + 0.0],
        [-r02 + 0.0, -r12 + 0.0, -r22 + 0.0],
    ]
    tx, ty, tz = (-np.array(R_gl_world) @ T_world_cam[:3, 3]).tolist()
    (g00, g01, g02), (g10, g11, g12), (g20, g21, g22) = R_gl_world
    return [g00, g10, g20, 0.0, g01, g11, g21, 0.0, g02, g12, g22, 0.0, tx, ty, tz, 1.0]


def world_to_camera(T_world_cam: np.ndarray, points_world: np.ndarray) -> np.ndarray:
    """Points (N, 3) in the world frame expressed in the camera frame."""
    R = T_world_cam[:3, :3]
    return (np.asarray(points_world, dtype=float) - T_world_cam[:3, 3]) @ R


def project_points(K: np.ndarray, T_world_cam: np.ndarray, points_world: np.ndarray):
    """Pixel coordinates (N, 2) and depths (N,) of world points (N, 3).

    A point behind the camera has depth <= 0; its pixel coordinates are meaningless.
    """
    p_cam = world_to_camera(T_world_cam, points_world)
    depth = p_cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = (p_cam[:, :2] / depth[:, None]) * np.diag(K)[:2] + K[:2, 2]
    return uv, depth


def sphere_image(K: np.ndarray, T_world_cam: np.ndarray, centre_world, radius_m: float):
    """The exact image of a sphere: an ellipse. Returns (centre_uv (2,), semi_major_px,
    semi_minor_px), or None when the camera is inside the sphere or the sphere is not
    wholly in front of the camera.

    The rays m = (x, y, 1) (normalised image coordinates) tangent to a sphere of centre S
    and radius r (camera frame) form the cone (m.S)^2 = |m|^2 (|S|^2 - r^2): the conic
    m^T Q m = 0 with Q = S S^T - (|S|^2 - r^2) I. Pixels are an affine map of (x, y), so
    the ellipse's centre maps through K and its quadratic part scales by 1/f. A detector's
    minimum enclosing circle of the blob has this centre and the semi-major axis.
    Written out for 2x2 blocks: NumPy's small-matrix calls cost ~100 us here.
    """
    sx, sy, sz = world_to_camera(T_world_cam, np.asarray(centre_world, dtype=float)[None])[0]
    k = sx * sx + sy * sy + sz * sz - radius_m * radius_m
    if k <= 0.0 or sz <= radius_m:
        return None
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    # Normalised conic: [x y] A [x y]^T + 2 b.[x y] + c = 0.
    a11, a12, a22 = sx * sx - k, sx * sy, sy * sy - k
    b1, b2, c = sx * sz, sy * sz, sz * sz - k
    det = a11 * a22 - a12 * a12
    if det <= 0.0:  # not an ellipse (the sphere reaches the camera's plane)
        return None
    xc = -(a22 * b1 - a12 * b2) / det
    yc = -(a11 * b2 - a12 * b1) / det
    f_centre = c + b1 * xc + b2 * yc
    # Quadratic part in pixels: D^-1 A D^-1 with D = diag(fx, fy); its eigenvalues.
    p11, p12, p22 = a11 / (fx * fx), a12 / (fx * fy), a22 / (fy * fy)
    mean, half_gap = 0.5 * (p11 + p22), np.hypot(0.5 * (p11 - p22), p12)
    lam_small, lam_large = abs(mean) - half_gap, abs(mean) + half_gap  # |eigenvalues|
    semi_major = np.sqrt(abs(f_centre) / lam_small)
    semi_minor = np.sqrt(abs(f_centre) / lam_large)
    return np.array([fx * xc + cx, fy * yc + cy]), float(semi_major), float(semi_minor)


class Camera:
    """Renders RGB frames of a :class:`Simulation` with PyBullet's TinyRenderer.

    Args:
        sim: the world to render.
        intrinsics: the pinhole calibration.
        near_m, far_m: OpenGL clipping planes; keep ``far_m`` tight around the scene.
    """

    def __init__(
        self,
        sim: Simulation,
        intrinsics: PinholeIntrinsics,
        near_m: float = 0.05,
        far_m: float = 5.0,
    ) -> None:
        self.sim = sim
        self.intrinsics = intrinsics
        self.K = intrinsics.K
        self._projection = intrinsics.gl_projection(near_m, far_m)
        self._view: tuple[bytes, list[float]] | None = None  # the last pose's view matrix

    def render(self, T_world_cam: np.ndarray) -> np.ndarray:
        """An RGB frame, uint8, shape (height, width, 3)."""
        w, h = self.intrinsics.width_px, self.intrinsics.height_px
        pose = T_world_cam.tobytes()  # a camera that stays put keeps its view matrix
        if self._view is None or self._view[0] != pose:
            self._view = (pose, gl_view_matrix(T_world_cam))
        _, _, rgba, _, _ = self.sim.client.getCameraImage(
            w,
            h,
            viewMatrix=self._view[1],
            projectionMatrix=self._projection,
            renderer=pybullet.ER_TINY_RENDERER,
            flags=pybullet.ER_NO_SEGMENTATION_MASK,
            shadow=0,
        )
        if getattr(rgba, "shape", None) != (h, w, 4):  # NumPy-enabled PyBullet: it is already
            rgba = np.reshape(rgba, (h, w, 4))
        return cv2.cvtColor(rgba, cv2.COLOR_RGBA2RGB)  # a new array
