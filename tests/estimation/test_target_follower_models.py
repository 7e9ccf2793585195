"""The robot image Jacobian B_i (spec (2)-(4)) against finite differences of the env's
simulated projection, its determinant and the singularity (18)(19)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from observer_gym.envs.target_follower import geometry as geo
from observer_gym.estimation.target_follower.models import (
    TargetFollowerCameraParams,
    image_state_transition,
    robot_jacobian,
    singularity_margin,
)

PARAMS = TargetFollowerCameraParams()  # Table 1
K = np.array([[PARAMS.fx_px, 0.0, 160.0], [0.0, PARAMS.fy_px, 120.0], [0.0, 0.0, 1.0]])


def _image_state(xy, yaw, tilt, target, params=PARAMS):
    T = geo.camera_pose(np.asarray(xy), yaw, tilt, params.delta_y_m)
    return geo.image_state(K, T, target, params.target_width_m)


def _finite_difference_jacobian(xy, yaw, tilt, target, h=1e-6):
    """d X_i / d (v, omega, omega_t) of the simulated projection, by central differences:
    moving forward by h, turning by h, tilting by h."""
    forward = np.array([math.cos(yaw), math.sin(yaw)])
    moves = [
        lambda s: (xy + s * forward, yaw, tilt),
        lambda s: (xy, yaw + s, tilt),
        lambda s: (xy, yaw, tilt + s),
    ]
    return np.column_stack(
        [(_image_state(*m(h), target) - _image_state(*m(-h), target)) / (2 * h) for m in moves]
    )


def _random_configuration(rng):
    xy, yaw, tilt = rng.uniform(-2, 2, 2), rng.uniform(-math.pi, math.pi), rng.uniform(-0.3, 1.0)
    T = geo.camera_pose(xy, yaw, tilt, PARAMS.delta_y_m)
    p_cam = [rng.uniform(-0.4, 0.4), rng.uniform(-0.3, 0.3), rng.uniform(0.6, 3.0)]
    return xy, yaw, tilt, T[:3, :3] @ p_cam + T[:3, 3]


def test_robot_jacobian_matches_finite_differences_of_the_projection():
    rng = np.random.default_rng(0)
    worst = 0.0
    for _ in range(200):
        xy, yaw, tilt, target = _random_configuration(rng)
        X_i = _image_state(xy, yaw, tilt, target)
        B = robot_jacobian(X_i, tilt, PARAMS)
        B_fd = _finite_difference_jacobian(xy, yaw, tilt, target)
        worst = max(worst, float(np.abs(B - B_fd).max() / np.abs(B_fd).max()))
    print(f"\nB_i vs finite differences, 200 configurations: worst relative error {worst:.1e}")
    assert worst < 1e-6


def test_robot_jacobian_follows_the_parameters():
    # Other f_x, f_y, W, delta_y: the projection and B_i change together.
    params = TargetFollowerCameraParams(
        fx_px=600.0, fy_px=580.0, target_width_m=0.3, delta_y_m=0.25
    )
    K2 = np.array([[600.0, 0.0, 320.0], [0.0, 580.0, 240.0], [0.0, 0.0, 1.0]])
    xy, yaw, tilt = np.array([0.3, -0.2]), 0.4, 0.5
    target = np.array([2.0, 1.2, 2.4])

    def X(xy_, yaw_, tilt_):
        T = geo.camera_pose(xy_, yaw_, tilt_, 0.25)
        return geo.image_state(K2, T, target, 0.3)

    h = 1e-6
    fwd = np.array([math.cos(yaw), math.sin(yaw)])
    B_fd = np.column_stack(
        [
            (X(xy + h * fwd, yaw, tilt) - X(xy - h * fwd, yaw, tilt)) / (2 * h),
            (X(xy, yaw + h, tilt) - X(xy, yaw - h, tilt)) / (2 * h),
            (X(xy, yaw, tilt + h) - X(xy, yaw, tilt - h)) / (2 * h),
        ]
    )
    np.testing.assert_allclose(robot_jacobian(X(xy, yaw, tilt), tilt, params), B_fd, atol=1e-5)


def test_determinant_closed_form():
    rng = np.random.default_rng(1)
    for _ in range(50):
        X_i = np.array([rng.uniform(-150, 150), rng.uniform(-110, 110), rng.uniform(10, 80)])
        tilt = rng.uniform(-0.3, 1.2)
        m = singularity_margin(X_i, tilt, PARAMS)
        expected = -(X_i[2] ** 2) * m**2 / (PARAMS.target_width_m * PARAMS.fy_px)
        assert np.linalg.det(robot_jacobian(X_i, tilt, PARAMS)) == pytest.approx(expected, rel=1e-9)


def test_singularity_18_makes_the_simulated_projection_lose_rank():
    # Choose y_i so that f_y = (y_i + S d_x) tan(phi) (18), S = f_y delta_y / (f_x W) (19):
    # the target straight above the robot's axle.
    tilt, d_x, x_i = 0.9, 30.0, 12.0
    S = PARAMS.fy_px * PARAMS.delta_y_m / (PARAMS.fx_px * PARAMS.target_width_m)
    y_i = PARAMS.fy_px / math.tan(tilt) - S * d_x
    X_i = np.array([x_i, y_i, d_x])
    assert singularity_margin(X_i, tilt, PARAMS) == pytest.approx(0.0, abs=1e-9)
    s = np.linalg.svd(robot_jacobian(X_i, tilt, PARAMS), compute_uv=False)
    assert s[-1] / s[0] < 1e-12
    # The env's projection at that image state: place the target where it projects to X_i.
    T = geo.camera_pose(np.zeros(2), 0.0, tilt, PARAMS.delta_y_m)
    z_c = PARAMS.fx_px * PARAMS.target_width_m / d_x
    p_cam = np.array([x_i * z_c / PARAMS.fx_px, -y_i * z_c / PARAMS.fy_px, z_c])
    target = T[:3, :3] @ p_cam + T[:3, 3]
    # Straight above the axle (world x = 0, the robot at the origin facing +x).
    assert abs(target[0]) < 1e-9
    s_fd = np.linalg.svd(
        _finite_difference_jacobian(np.zeros(2), 0.0, tilt, target), compute_uv=False
    )
    assert s_fd[-1] / s_fd[0] < 1e-6


def test_transition_is_30():
    B = np.arange(9.0).reshape(3, 3)
    F, G = image_state_transition(0.1, B)
    np.testing.assert_array_equal(F[:3, 3:], 0.1 * np.eye(3))
    np.testing.assert_array_equal(F[3:, :3], np.zeros((3, 3)))
    np.testing.assert_array_equal(G[:3], 0.1 * B)
    np.testing.assert_array_equal(G[3:], np.zeros((3, 3)))


def test_scaled_parameters():
    p = PARAMS.scaled([0.1, -0.1, 0.05, 0.0])
    assert (p.fx_px, p.fy_px) == pytest.approx((393.4 * 1.1, 391.8 * 0.9))
    assert (p.target_width_m, p.delta_y_m) == pytest.approx((0.126, 0.10))
    with pytest.raises(ValueError, match="fx_px"):
        TargetFollowerCameraParams(fx_px=0.0)
