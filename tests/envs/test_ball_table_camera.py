"""Camera geometry and the measurements mode against rendered frames: what the env says a
perfect detector sees must be what is in the picture."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from observer_gym.envs.ball_table.layout import BALL_PX, CORNERS_PX, DETECTED
from observer_gym.envs.camera import (
    PinholeIntrinsics,
    gl_view_matrix,
    look_at,
    project_points,
    sphere_image,
)
from observer_gym.envs.target_follower import geometry as follower_geo


def test_intrinsics_from_fov_match_the_spec():
    intr = PinholeIntrinsics.from_fov(320, 240, 90.0)
    np.testing.assert_allclose(intr.K, [[160, 0, 160], [0, 160, 120], [0, 0, 1]], atol=1e-9)


def test_look_at_target_projects_to_the_principal_point():
    K = PinholeIntrinsics.from_fov(320, 240, 90.0).K
    T = look_at([0.3, -0.2, 1.5], [0.6, 0.1, 0.9])
    uv, depth = project_points(K, T, np.array([[0.6, 0.1, 0.9], [0.3, -0.2, 2.0]]))
    np.testing.assert_allclose(uv[0], K[:2, 2], atol=1e-9)
    assert depth[0] > 0 and depth[1] < 0  # the second point is behind the camera


def _gl_view_matrix_by_matrix_products(T_world_cam):
    """gl_view_matrix as NumPy's matrix products (as it was computed before)."""
    view = np.eye(4)
    R_gl_world = np.diag([1.0, -1.0, -1.0]) @ T_world_cam[:3, :3].T
    view[:3, :3] = R_gl_world
    view[:3, 3] = -R_gl_world @ T_world_cam[:3, 3]
    return view.T.reshape(-1).tolist()


def test_gl_view_matrix_equals_the_matrix_products_bit_for_bit():
    rng = np.random.default_rng(0)
    poses = [look_at(rng.normal(size=3), rng.normal(size=3)) for _ in range(3000)]
    # Poses with zero entries of both signs: axis-aligned cameras, the follower's camera.
    poses += [look_at([0.0, 0.0, 1.0], [0.0, 0.5, 0.0]), look_at([1.0, -0.0, 0.0], [0.0, 0.0, 0.0])]
    angles = [0.0, -0.0, 0.3, np.pi / 2, -np.pi]
    poses += [
        follower_geo.camera_pose(np.array([x, -x]), yaw, tilt, 0.1)
        for x in (0.0, -0.0, 0.7)
        for yaw in angles
        for tilt in angles
    ]
    poses += [T.copy() for T in poses[-20:]]
    for T in poses:
        T[np.abs(T) < 1e-3] *= rng.choice([0.0, -0.0])  # more exact zeros
        expected = np.array(_gl_view_matrix_by_matrix_products(T))
        assert np.array(gl_view_matrix(T)).tobytes() == expected.tobytes()


def test_sphere_image_touches_the_projected_tangent_circle():
    """The sphere's silhouette is the image of its circle of tangency; that circle's
    projected points must reach exactly the ellipse's semi-major and semi-minor axes."""
    rng = np.random.default_rng(0)
    K = np.array([[300.0, 0, 170], [0, 280.0, 130], [0, 0, 1]])
    for _ in range(50):
        T = look_at(np.array([0.0, 0.0, 2.0]) + rng.normal(size=3), rng.normal(size=3) * 0.2)
        centre = rng.normal(size=3) * 0.2
        radius = rng.uniform(0.02, 0.3)
        S = (centre - T[:3, 3]) @ T[:3, :3]
        d2 = S @ S
        # Tangency circle: centre S (1 - r^2/|S|^2), radius r sqrt(1 - r^2/|S|^2), normal S.
        c_cam = S * (1 - radius**2 / d2)
        rho = radius * np.sqrt(1 - radius**2 / d2)
        e1 = np.cross(S, [1.0, 0, 0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(S / np.sqrt(d2), e1)
        angles = np.linspace(0, 2 * np.pi, 4000, endpoint=False)
        pts_cam = c_cam + rho * (np.outer(np.cos(angles), e1) + np.outer(np.sin(angles), e2))
        pts_world = pts_cam @ T[:3, :3].T + T[:3, 3]
        uv, _ = project_points(K, T, pts_world)
        centre_uv, semi_major, semi_minor = sphere_image(K, T, centre, radius)
        dist = np.linalg.norm(uv - centre_uv, axis=1)
        assert dist.max() == pytest.approx(semi_major, rel=1e-5)
        assert dist.min() == pytest.approx(semi_minor, rel=1e-5)


# --- rendered frames ------------------------------------------------------------------


def _red_mask(rgb):
    r, g, b = (rgb[..., i].astype(int) for i in range(3))
    return ((r > 120) & (g < 80) & (b < 80)).astype(np.uint8)


def _green_mask(rgb):
    r, g, b = (rgb[..., i].astype(int) for i in range(3))
    return ((g > 100) & (r < 100) & (b < 100)).astype(np.uint8)


def _largest_contour(mask):
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    return max(contours, key=cv2.contourArea).reshape(-1, 2).astype(float)


def _red_top_corners(rgb) -> np.ndarray:
    """Sub-pixel corners of the red top: each side's line is fitted through the boundary
    pixels just inside and just outside the red region (their mid-line is the edge)."""
    mask = _red_mask(rgb)
    inner = _largest_contour(mask)
    outer = _largest_contour(cv2.dilate(mask, np.ones((3, 3), np.uint8)))
    rough = cv2.approxPolyDP(inner.astype(np.float32), 3.0, True).reshape(-1, 2)
    assert len(rough) == 4, f"red top outline has {len(rough)} vertices"
    lines = []
    for i in range(4):
        a, b = rough[i], rough[(i + 1) % 4]
        direction = (b - a) / np.linalg.norm(b - a)
        normal = np.array([-direction[1], direction[0]])
        pts = np.vstack([inner, outer])
        along = (pts - a) @ direction
        across = np.abs((pts - a) @ normal)
        keep = (along > 4) & (along < np.linalg.norm(b - a) - 4) & (across < 2.5)
        vx, vy, x0, y0 = cv2.fitLine(pts[keep].astype(np.float32), cv2.DIST_L2, 0, 0.01, 0.01)
        lines.append((np.array([x0[0], y0[0]]), np.array([vx[0], vy[0]])))
    corners = []
    for i in range(4):
        (p, u), (q, v) = lines[i - 1], lines[i]
        t = np.linalg.solve(np.column_stack([u, -v]), q - p)
        corners.append(p + t[0] * u)
    return np.array(corners)


def _paired_frames(make_env, seed, steps, **kwargs):
    """Rendered frames and perfect measurements of the same physics (same seed and
    actions; rendering does not touch the physics)."""
    rgb_env = make_env(obs_mode="rgb", start_radius_m=0.06, **kwargs)
    meas_env = make_env(obs_mode="measurements", start_radius_m=0.06, **kwargs)
    frame, _ = rgb_env.reset(seed=seed)
    meas, _ = meas_env.reset(seed=seed)
    pairs = [(frame, meas)]
    rng = np.random.default_rng(seed)
    for _ in range(steps):
        action = rng.uniform(-0.03, 0.03, size=2).astype(np.float32)
        frame, *_ = rgb_env.step(action)
        meas, *_ = meas_env.step(action)
        pairs.append((frame, meas))
    return pairs


@pytest.mark.parametrize("camera_motion", ["fixed", "head"])
def test_measurements_agree_with_the_rendered_frame_within_one_pixel(make_env, camera_motion):
    pairs = _paired_frames(make_env, seed=4, steps=25, camera_motion=camera_motion)
    worst_ball, worst_radius, worst_corner = 0.0, 0.0, 0.0
    for frame, meas in pairs[::5]:
        assert meas[DETECTED].tolist() == [1, 1]
        green = _green_mask(frame)
        m = cv2.moments(green, binaryImage=True)
        centroid = np.array([m["m10"] / m["m00"], m["m01"] / m["m00"]])
        worst_ball = max(worst_ball, np.linalg.norm(centroid - meas[BALL_PX][:2]))
        (_, _), radius = cv2.minEnclosingCircle(_largest_contour(green).astype(np.float32))
        worst_radius = max(worst_radius, abs(radius - meas[BALL_PX][2]))
        detected = _red_top_corners(frame)
        expected = meas[CORNERS_PX].reshape(4, 2)
        # Match each expected corner to the nearest detected one (order-free).
        dists = np.linalg.norm(expected[:, None] - detected[None], axis=2)
        worst_corner = max(worst_corner, dists.min(axis=1).max())
    assert worst_ball < 1.0
    assert worst_radius < 1.0
    assert worst_corner < 1.0


def test_occluded_ball_is_reported_missing_exactly_when_hidden_in_the_frame(make_env):
    pairs = _paired_frames(make_env, seed=2, steps=150, occluder_rate_hz=2.0, occluder_pass_s=1.0)
    full_area = np.pi * pairs[0][1][BALL_PX][2] ** 2
    hidden_frames = visible_frames = 0
    for frame, meas in pairs:
        area = int(_green_mask(frame).sum())
        if area == 0:  # wholly hidden in the picture
            assert meas[DETECTED][1] == 0
            hidden_frames += 1
        elif area > 0.9 * full_area:  # wholly visible
            assert meas[DETECTED][1] == 1
            visible_frames += 1
    assert hidden_frames >= 3 and visible_frames >= 50  # both cases really happened


def test_table_partly_out_of_view_is_flagged(make_env):
    env = make_env(obs_mode="measurements", hfov_deg=25.0, start_radius_m=0.0)
    meas, _ = env.reset(seed=0)
    assert meas[DETECTED].tolist() == [0, 1]  # corners outside the image, ball at the centre
    np.testing.assert_array_equal(meas[CORNERS_PX], 0.0)
