"""``obs_mode="measurements"``: what a perfect TargetFollower detector reports, without
rendering, under the spec's noise model.

The detection is the image state (x_i, y_i, d_x) of the target (geometry.image_state).
The target is found when its centre lies in front of the camera and inside the image and
it is not fully hidden: the occluder hides it when the lines of sight to its centre and
to the four extreme points of its silhouette (left, right, top, bottom) all pass through
the occluder. The noise is the spec's simulation model, Table 2:
Z = round(X + sigma_n (2 w - 1)), w ~ U[0, 1] per entry (rounding optional).
"""

from __future__ import annotations

import numpy as np

from observer_gym.envs.ball_table.measurements import segment_hits_box
from observer_gym.envs.target_follower.geometry import MIN_DEPTH_M, image_state
from observer_gym.envs.target_follower.layout import DETECTED, TARGET_PX
from observer_gym.envs.target_follower.motion import OCCLUDER_HALF_EXTENTS_M


def empty_measurement() -> dict:
    return {TARGET_PX: np.zeros(3, dtype=np.float32), DETECTED: np.zeros(1, dtype=np.int8)}


def in_image(K: np.ndarray, image_size_px: tuple[int, int], x_i: float, y_i: float) -> bool:
    """Whether the image-state point (x_i, y_i) lies on the image."""
    u, v = x_i + K[0, 2], K[1, 2] - y_i
    return 0.0 <= u <= image_size_px[0] - 1 and 0.0 <= v <= image_size_px[1] - 1


def fully_hidden(T_world_cam: np.ndarray, target_world: np.ndarray, radius_m: float, occluder):
    """Whether the occluder (centre_world, yaw_rad) hides all of the target's silhouette."""
    if occluder is None:
        return False
    centre, yaw = occluder
    c, s = np.cos(yaw), np.sin(yaw)
    rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    eye = T_world_cam[:3, 3]
    right, down = T_world_cam[:3, 0], T_world_cam[:3, 1]
    target = np.asarray(target_world, dtype=float)
    points = [target] + [
        target + sign * radius_m * axis for axis in (right, down) for sign in (1, -1)
    ]
    return all(segment_hits_box(eye, p, centre, rotation, OCCLUDER_HALF_EXTENTS_M) for p in points)


def perfect_measurement(
    K: np.ndarray,
    T_world_cam: np.ndarray,
    image_size_px: tuple[int, int],
    target_world: np.ndarray,
    width_m: float,
    occluder=None,
    noise_px: float = 0.0,
    rounding: bool = True,
    rng: np.random.Generator | None = None,
) -> dict:
    """The measurement of one frame (see the module docstring)."""
    out = empty_measurement()
    # Always draw the same count, so the random stream does not depend on visibility.
    w = rng.uniform(size=3) if rng is not None else np.full(3, 0.5)
    depth = (T_world_cam[:3, :3].T @ (np.asarray(target_world) - T_world_cam[:3, 3]))[2]
    if depth <= MIN_DEPTH_M:
        return out
    X = image_state(K, T_world_cam, target_world, width_m)
    if not in_image(K, image_size_px, X[0], X[1]):
        return out
    if fully_hidden(T_world_cam, target_world, 0.5 * width_m, occluder):
        return out
    Z = X + noise_px * (2.0 * w - 1.0)  # Table 2: X + sigma_n (2 w - 1)
    if rounding:
        Z = np.round(Z)
    out[TARGET_PX][:] = Z
    out[DETECTED][0] = 1
    return out
