"""``obs_mode="measurements"``: what a perfect BallTable detector reports, without rendering.

For the red top, the pixel coordinates of its four corners; for the ball, the centre and
semi-major axis of its exact image ellipse (what a minimum enclosing circle of the green
blob gives, spec "Ball position on the table", step 1). A feature counts as found only if
it lies in front of the camera, inside the image, and is not hidden by the occluder.
Gaussian pixel noise (std ``noise_px``) is added to every coordinate.
"""

from __future__ import annotations

import numpy as np

from observer_gym.envs.ball_table import geometry as geo
from observer_gym.envs.ball_table.layout import BALL_PX, CORNERS_PX, DETECTED
from observer_gym.envs.camera import project_points, sphere_image


def segment_hits_box(start, end, box_centre, box_rotation, half_extents) -> bool:
    """Whether the segment start->end passes through an oriented box (slab test)."""
    s = box_rotation.T @ (np.asarray(start) - box_centre)
    d = box_rotation.T @ (np.asarray(end) - np.asarray(start))
    t_enter, t_exit = 0.0, 1.0
    for axis in range(3):
        if abs(d[axis]) < 1e-12:
            if abs(s[axis]) > half_extents[axis]:
                return False
            continue
        t0 = (-half_extents[axis] - s[axis]) / d[axis]
        t1 = (half_extents[axis] - s[axis]) / d[axis]
        t_enter = max(t_enter, min(t0, t1))
        t_exit = min(t_exit, max(t0, t1))
        if t_enter > t_exit:
            return False
    return True


def empty_measurement() -> dict:
    return {
        CORNERS_PX: np.zeros(8, dtype=np.float32),
        BALL_PX: np.zeros(3, dtype=np.float32),
        DETECTED: np.zeros(2, dtype=np.int8),
    }


def perfect_measurement(
    K: np.ndarray,
    T_world_cam: np.ndarray,
    image_size_px: tuple[int, int],
    T_world_table: np.ndarray,
    ball_pos_world: np.ndarray,
    occluder=None,
    noise_px: float = 0.0,
    rng: np.random.Generator | None = None,
) -> dict:
    """The measurement of one frame.

    Args:
        occluder: None, or (centre_world, rotation, half_extents) of a box that hides
            whatever is behind it.
        noise_px: std of the Gaussian pixel noise (needs ``rng`` when > 0).
    """
    width, height = image_size_px
    eye = T_world_cam[:3, 3]

    def hidden(point_world) -> bool:
        return occluder is not None and segment_hits_box(eye, point_world, *occluder)

    def in_image(uv) -> bool:
        return 0.0 <= uv[0] <= width - 1 and 0.0 <= uv[1] <= height - 1

    out = empty_measurement()
    corners_world = geo.TABLE_CORNERS_TABLE @ T_world_table[:3, :3].T + T_world_table[:3, 3]
    corners_uv, depth = project_points(K, T_world_cam, corners_world)
    if depth.min() > 0 and all(in_image(uv) for uv in corners_uv.tolist()):
        if not any(hidden(c) for c in corners_world):
            out[CORNERS_PX][:] = corners_uv.reshape(-1)
            out[DETECTED][0] = 1
    ellipse = sphere_image(K, T_world_cam, ball_pos_world, geo.BALL_RADIUS_M)
    if ellipse is not None and in_image(ellipse[0]) and not hidden(ball_pos_world):
        out[BALL_PX][:2] = ellipse[0]
        out[BALL_PX][2] = ellipse[1]
        out[DETECTED][1] = 1
    if noise_px > 0.0:
        # Always draw the same count, so the random stream does not depend on visibility.
        assert rng is not None, "noise_px > 0 needs rng"
        corner_noise = rng.normal(0.0, noise_px, size=(4, 2))
        ball_noise = rng.normal(0.0, noise_px, size=3)
        if out[DETECTED][0]:
            noisy = np.clip(corners_uv + corner_noise, 0, [width - 1, height - 1])
            out[CORNERS_PX][:] = noisy.reshape(-1)
        if out[DETECTED][1]:
            noisy = out[BALL_PX] + ball_noise
            out[BALL_PX][:2] = np.clip(noisy[:2], 0, [width - 1, height - 1])
            out[BALL_PX][2] = max(noisy[2], 0.0)
    return out
