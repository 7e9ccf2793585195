"""Synthetic throws seen by calibrated cameras: the scenario of the viewline filter's tests
and of ``observer-gym reproduce linderoth2010`` (docs/spec/catcher.md, "Results to reproduce").

Frame: the paper's coordinates (x_p, y_p, z_p) have y up and the ball coming in along
-z_p; ours are z up with the thrower on +x, as in BallCatcher-v1, so (x, y, z) =
(z_p, x_p, y_p) (a cyclic permutation: right-handed both). The paper's two-camera init,
position (0, 0, 3) and velocity (0, 0, -8), is therefore (3, 0, 0) and (-8, 0, 0) here
(:data:`PAPER_X0`), with the origin at the catch point, where the paper's throws end.

Throws are drag-free (the filter's model is exact; process noise only stands for what a
real ball adds) from about 4.5 m out at about 8 m/s, crossing x = 0 near the origin.
Cameras are 656 x 480 px (the paper's), 75 deg horizontal field of view, one frame every
20 ms in all; pixel noise Gaussian, 0.5 px per axis unless stated.

Also here: :func:`pixel_crlb_cov`, the Cramer-Rao bound of the pixel measurements, the
covariance no unbiased estimator can beat; it shows what a single camera can know after k
frames whatever the filter.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from observer_gym.envs.camera import PinholeIntrinsics, look_at, project_points
from observer_gym.envs.sim import GRAVITY_MPS2

__all__ = [
    "FRAME_PERIOD_S",
    "PAPER_P0",
    "PAPER_X0",
    "RIG_CAMERAS",
    "RIG_INTRINSICS",
    "SINGLE_CAMERA",
    "SINGLE_CAMERA_P0",
    "SimCamera",
    "SyntheticFrame",
    "Throw",
    "alternating_frames",
    "far_initial_states",
    "pixel_crlb_cov",
    "random_throw",
    "single_camera_frames",
]

FRAME_PERIOD_S = 0.02  # the paper: one image every 20 ms (from either camera)
GRAVITY_WORLD = np.array([0.0, 0.0, -GRAVITY_MPS2])

# The paper's two-camera init, mapped to our frame (see the module docstring), and its
# variance 10^2 in all directions.
PAPER_X0 = np.array([3.0, 0.0, 0.0, -8.0, 0.0, 0.0])
PAPER_P0 = 10.0**2 * np.eye(6)
# Single camera: position std 100 m (the paper's), velocity std 10 m/s (a hand throw is
# well under 15 m/s; the paper does not say); velocity guess zero.
SINGLE_CAMERA_P0 = np.diag([100.0**2] * 3 + [10.0**2] * 3)


@dataclass(frozen=True)
class SimCamera:
    """A calibrated synthetic camera: intrinsics, pose (camera to world, OpenCV axes)."""

    name: str
    intrinsics: PinholeIntrinsics
    T_world_cam: np.ndarray

    @property
    def K(self) -> np.ndarray:
        return self.intrinsics.K

    def project(self, point_world: np.ndarray) -> tuple[np.ndarray, bool]:
        """(pixel (2,), whether it is in front of the camera and inside the image)."""
        uv, depth = project_points(self.K, self.T_world_cam, np.asarray(point_world)[None])
        uv = uv[0]
        w, h = self.intrinsics.width_px, self.intrinsics.height_px
        inside = bool(depth[0] > 0.0 and 0.0 <= uv[0] <= w - 1 and 0.0 <= uv[1] <= h - 1)
        return uv, inside


RIG_INTRINSICS = PinholeIntrinsics.from_fov(656, 480, 75.0)  # f = 427 px
# Two cameras beside the flight, 3 m out on either side, 0.6 m above the catch point,
# both aimed at the middle of the flight: their viewlines cross at about 90 deg there.
# The whole tracked flight (x from 4.7 m to 0.6 m) is inside both images.
RIG_CAMERAS = (
    SimCamera("camera 1", RIG_INTRINSICS, look_at((2.25, -3.0, 0.6), (2.25, 0.0, 0.1))),
    SimCamera("camera 2", RIG_INTRINSICS, look_at((2.25, 3.0, 0.6), (2.25, 0.0, 0.1))),
)
# The single static camera: 2 m beside the flight, aimed across it at x = 3 m. It sees the
# ball from 20-40 ms after release for 17-22 frames (x from ~4.3 m to ~1 m). Nearer
# would see more per frame but fewer frames; see pixel_crlb_cov for what it can know.
SINGLE_CAMERA = SimCamera("side camera", RIG_INTRINSICS, look_at((3.0, -2.0, 0.3), (3.0, 0.0, 0.1)))


@dataclass(frozen=True)
class Throw:
    """A drag-free throw: release position (m) and velocity (m/s) at t = 0, world frame."""

    pos0_world: np.ndarray
    vel0_world: np.ndarray

    def state(self, t_s: float | np.ndarray) -> np.ndarray:
        """Exact state(s) (x, y, z, vx, vy, vz), (6,) or (N, 6), at ``t_s`` after release."""
        t = np.asarray(t_s, dtype=float)[..., None]
        pos = self.pos0_world + self.vel0_world * t + 0.5 * GRAVITY_WORLD * t * t
        return np.concatenate([pos, self.vel0_world + GRAVITY_WORLD * t], axis=-1)


def random_throw(rng: np.random.Generator) -> Throw:
    """Release within +-0.2 m of (4.5, 0, 0), crossing x = 0 within 0.2 m of the origin
    after 0.5-0.65 s: a horizontal speed of 7-9.4 m/s, like the paper's 8 m/s."""
    p0 = np.array([4.5, 0.0, 0.0]) + rng.uniform(-0.2, 0.2, 3)
    radius, angle = 0.2 * np.sqrt(rng.uniform()), rng.uniform(0.0, 2.0 * np.pi)
    crossing = radius * np.array([0.0, np.cos(angle), np.sin(angle)])
    flight_s = rng.uniform(0.5, 0.65)
    v0 = (crossing - p0) / flight_s - 0.5 * GRAVITY_WORLD * flight_s
    return Throw(p0, v0)


@dataclass(frozen=True)
class SyntheticFrame:
    """One frame: its capture time (s after release), camera, the noisy detection (None
    if the ball is outside the image), the true state then and whether ``uv_px`` is an
    injected outlier."""

    capture_time_s: float
    camera: SimCamera
    uv_px: np.ndarray | None
    true_state: np.ndarray
    outlier: bool = False

    @property
    def K(self) -> np.ndarray:
        return self.camera.K

    @property
    def T_world_cam(self) -> np.ndarray:
        return self.camera.T_world_cam


def _frame(
    throw: Throw,
    camera: SimCamera,
    t_s: float,
    pixel_std_px: float,
    rng: np.random.Generator,
    outlier_prob: float,
    min_outlier_px: float,
) -> SyntheticFrame:
    state = throw.state(t_s)
    uv, inside = camera.project(state[:3])
    if not inside:
        return SyntheticFrame(t_s, camera, None, state)
    uv = uv + rng.normal(scale=pixel_std_px, size=2)
    if outlier_prob > 0.0 and rng.random() < outlier_prob:
        size = np.array([camera.intrinsics.width_px, camera.intrinsics.height_px]) - 1.0
        while True:  # a detection elsewhere in the image: another object, a reflection
            bad = rng.uniform([0.0, 0.0], size)
            if np.linalg.norm(bad - uv) >= min_outlier_px:
                return SyntheticFrame(t_s, camera, bad, state, outlier=True)
    return SyntheticFrame(t_s, camera, uv, state)


def alternating_frames(
    throw: Throw,
    n_frames: int,
    rng: np.random.Generator,
    cameras: Sequence[SimCamera] = RIG_CAMERAS,
    pixel_std_px: float = 0.5,
    outlier_prob: float = 0.0,
    outlier_after: int = 0,
    min_outlier_px: float = 40.0,
) -> list[SyntheticFrame]:
    """Frames k = 1..n at k x 20 ms after release, camera 1 at odd k, camera 2 at even k
    (the paper's schedule). After frame ``outlier_after``, each detection is replaced with
    probability ``outlier_prob`` by a uniform pixel at least ``min_outlier_px`` from it."""
    return [
        _frame(
            throw,
            cameras[(k - 1) % len(cameras)],
            k * FRAME_PERIOD_S,
            pixel_std_px,
            rng,
            outlier_prob if k > outlier_after else 0.0,
            min_outlier_px,
        )
        for k in range(1, n_frames + 1)
    ]


def single_camera_frames(
    throw: Throw,
    n_frames: int,
    rng: np.random.Generator,
    camera: SimCamera = SINGLE_CAMERA,
    pixel_std_px: float = 0.5,
) -> list[SyntheticFrame]:
    """Frames k = 1..n at k x 20 ms after release from one static camera (50 Hz)."""
    return alternating_frames(throw, n_frames, rng, (camera,), pixel_std_px)


def far_initial_states(
    throw: Throw, n: int, distance_m: float = 70.0, seed: int = 0
) -> list[np.ndarray]:
    """``n`` initial states whose positions lie ``distance_m`` from the release point in
    directions spread over the sphere (a Fibonacci lattice, rotated by ``seed``), with
    velocity zero."""
    rng = np.random.default_rng(seed)
    i = np.arange(n) + 0.5
    polar = np.arccos(1.0 - 2.0 * i / n)
    azimuth = np.pi * (1.0 + 5.0**0.5) * i + rng.uniform(0.0, 2.0 * np.pi)
    directions = np.column_stack(
        [np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar)]
    )
    return [np.concatenate([throw.pos0_world + distance_m * d, np.zeros(3)]) for d in directions]


def pixel_crlb_cov(frames: Sequence[SyntheticFrame], pixel_std_px: float) -> np.ndarray:
    """Cramer-Rao bound (6, 6) on the state at the last frame's time from the pixels of
    ``frames`` alone (no prior, drag-free model exact): the inverse of the Fisher
    information sum_i A_i^T A_i / sigma^2, A_i = d(pixel_i)/d(state), through the exact
    flight x(t_i) = Phi(t_i - t_last) x(t_last) + ... . No unbiased estimator's covariance
    is smaller; ``numpy.linalg.LinAlgError`` if the frames cannot determine the state."""
    t_last = frames[-1].capture_time_s
    info = np.zeros((6, 6))
    for frame in frames:
        if frame.uv_px is None:
            continue
        T = frame.T_world_cam
        p_cam = (frame.true_state[:3] - T[:3, 3]) @ T[:3, :3]
        x_c, y_c, z_c = p_cam
        fx, fy = frame.K[0, 0], frame.K[1, 1]
        # d(u, v)/d(p_world): the pinhole Jacobian times the world-to-camera rotation.
        J_cam = np.array([[fx / z_c, 0.0, -fx * x_c / z_c**2], [0.0, fy / z_c, -fy * y_c / z_c**2]])
        dt = frame.capture_time_s - t_last
        A = J_cam @ T[:3, :3].T @ np.hstack([np.eye(3), dt * np.eye(3)])
        info += A.T @ A / pixel_std_px**2
    return np.linalg.inv(info)
