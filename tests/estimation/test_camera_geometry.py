"""Camera geometry against envs.camera's projection and against plain 3D geometry."""

from __future__ import annotations

import numpy as np
import pytest

from observer_gym.envs.camera import PinholeIntrinsics, look_at, project_points
from observer_gym.estimation.camera_geometry import (
    pixel_ray,
    projection_matrix,
    ray_plane_intersection,
    viewline_planes,
)


def _random_camera(rng: np.random.Generator):
    """A 640x480 camera with a random field of view and pose, looking at the origin
    region, and random world points in front of it."""
    K = PinholeIntrinsics.from_fov(640, 480, rng.uniform(40.0, 100.0)).K
    K[0, 2] += rng.uniform(-20, 20)  # an off-centre principal point and fx != fy too
    K[1, 1] *= rng.uniform(0.9, 1.1)
    eye = rng.uniform(-3.0, 3.0, size=3) + np.array([0.0, 0.0, 4.0])
    T_world_cam = look_at(eye, rng.uniform(-0.5, 0.5, size=3), up_world=(0.3, 0.2, 1.0))
    points_world = rng.uniform(-1.0, 1.0, size=(50, 3))
    return K, T_world_cam, points_world


@pytest.mark.parametrize("seed", range(5))
def test_projection_matrix_agrees_with_project_points(seed):
    K, T_world_cam, points_world = _random_camera(np.random.default_rng(seed))
    P = projection_matrix(K, T_world_cam)
    x = np.column_stack([points_world, np.ones(len(points_world))]) @ P.T
    uv_expected, depth = project_points(K, T_world_cam, points_world)
    assert np.all(depth > 0)
    np.testing.assert_allclose(x[:, :2] / x[:, 2:], uv_expected, atol=1e-9)
    np.testing.assert_allclose(x[:, 2], depth, rtol=1e-12)  # P's third row gives the depth


@pytest.mark.parametrize("seed", range(5))
def test_viewline_planes_hold_the_point_and_measure_distance_off_it(seed):
    rng = np.random.default_rng(seed)
    K, T_world_cam, points_world = _random_camera(rng)
    P = projection_matrix(K, T_world_cam)
    uv, _ = project_points(K, T_world_cam, points_world)
    eye = T_world_cam[:3, 3]
    image_y_world, image_x_world = T_world_cam[:3, 1], T_world_cam[:3, 0]
    for X, pixel in zip(points_world, uv, strict=True):
        planes = viewline_planes(P, pixel)
        assert planes.shape == (2, 4)
        np.testing.assert_allclose(np.linalg.norm(planes[:, :3], axis=1), 1.0, rtol=1e-12)
        # (21)-(22): the point on the viewline satisfies pi[:3] . X = -pi[3].
        np.testing.assert_allclose(planes[:, :3] @ X, -planes[:, 3], atol=1e-9)
        # Independently: pi_x is the plane through the camera centre holding the ray to X
        # and the image's y axis (the image line u = const); pi_y holds the image's x axis.
        Y = X + rng.normal(0.0, 0.2, size=3)
        for plane, in_plane_axis in zip(planes, (image_y_world, image_x_world), strict=True):
            normal = np.cross(X - eye, in_plane_axis)
            normal /= np.linalg.norm(normal)
            geometric = abs(normal @ (Y - eye))
            assert geometric > 1e-4  # really off the plane
            np.testing.assert_allclose(abs(plane[:3] @ Y + plane[3]), geometric, atol=1e-9)


@pytest.mark.parametrize("seed", range(5))
def test_pixel_ray_through_a_projection_passes_through_the_point(seed):
    K, T_world_cam, points_world = _random_camera(np.random.default_rng(seed))
    uv, _ = project_points(K, T_world_cam, points_world)
    origin, directions = pixel_ray(K, T_world_cam, uv)
    np.testing.assert_allclose(origin, T_world_cam[:3, 3])
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0, rtol=1e-12)
    to_points = points_world - origin
    distance_along = np.einsum("ij,ij->i", to_points, directions)
    assert np.all(distance_along > 0)  # in front of the camera
    closest = origin + distance_along[:, None] * directions
    np.testing.assert_allclose(closest, points_world, atol=1e-9)
    # A single pixel gives a single ray.
    _, d1 = pixel_ray(K, T_world_cam, uv[0])
    assert d1.shape == (3,)
    np.testing.assert_allclose(d1, directions[0], atol=1e-12)


def test_ray_plane_intersection():
    origin = np.array([1.0, 2.0, 3.0])
    hit = ray_plane_intersection(origin, [0.0, 1.0, -1.0], [0.0, 0.0, 0.5], [0.0, 0.0, 2.0])
    np.testing.assert_allclose(hit, [1.0, 4.5, 0.5])
    assert ray_plane_intersection(origin, [1.0, 0.0, 0.0], [0, 0, 0], [0, 0, 1]) is None
    assert ray_plane_intersection(origin, [0.0, 0.0, 1.0], [0, 0, 0], [0, 0, 1]) is None
