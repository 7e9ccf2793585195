"""``ekf`` under a camera calibration error (estimation/ball_table/pixel_ekf.py): the table
centre's translation states absorb a pose error that it read as tilt before, and the
closed loop settles the ball. Ground truth from the simulator."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from observer_gym.envs.ball_table.geometry import TABLE_CENTRE_HOME_WORLD
from observer_gym.estimation.ball_table.pixel_ekf import centre_calibration_cov
from observer_gym.train.experiments.episode import EpisodeSpec, run_episode

ENV_ID = "observer_gym/BallTable-v0"
# the calibration sweep's setup (docs/results/sweeps/ball_table_rotation)
SWEEP = {"measurement_noise_px": 0.05, "push_rate_hz": 0.5, "calib_rotation_error_deg": 1.0}


@pytest.mark.parametrize("controller", ["lqr", pytest.param("mpc", marks=pytest.mark.slow)])
@pytest.mark.parametrize("seed", [0, pytest.param(1, marks=pytest.mark.slow)])  # 1.4-2.5 s each
def test_ekf_settles_the_ball_under_one_degree_of_rotation_error(controller, seed):
    """A whole episode (10 s, pushes at 0.5 Hz): the true ball ends within 5 mm of the
    centre and its mean distance over the last 2 s is below 1 cm, the sweeps' settling
    radius (measured, either controller: final 2.5 and 3.2 mm, last 2 s 5.1 and 4.7 mm;
    before the translation states, with MPC, final 122 and 99 mm: it lost the ball)."""
    run = run_episode(
        EpisodeSpec.of(ENV_ID, "ekf-measurements", controller, seed, env_kwargs=SWEEP)
    )
    distance_m = np.hypot(*run["state"][:, :2].T)
    last_2_s = float(distance_m[-100:].mean())
    print(f"\nfinal {distance_m[-1] * 1e3:.2f} mm, last 2 s mean {last_2_s * 1e3:.2f} mm")
    assert distance_m[-1] < 0.005, distance_m[-1]
    assert last_2_s < 0.01, last_2_s


def test_the_centre_s_calibration_prior_is_the_camera_moved(make_env):
    """At 1 degree of rotation error (per-axis variance (1 deg)^2 / 3) the home centre, at
    S_0 in the camera's frame, appears turned about the camera: across the line of sight
    only, trace 2 |S_0|^2 var. With 2 % focal error its depth grows with the focal length
    and its pixel stays: it moves along the optical axis by 2 % of its depth z_0."""
    env = make_env(ENV_ID, obs_mode="measurements").unwrapped
    env.reset(seed=0)
    K, T_world_cam = env.camera_intrinsics()[0].K, env.camera_pose(0)
    line = TABLE_CENTRE_HOME_WORLD - T_world_cam[:3, 3]
    z0 = float(line @ T_world_cam[:3, 2])
    spec = env.sensor_spec

    sigma = centre_calibration_cov(replace(spec, calib_rotation_error_deg=1.0), K, T_world_cam)
    var = np.radians(1.0) ** 2 / 3.0
    np.testing.assert_allclose(np.trace(sigma), 2.0 * (line @ line) * var, rtol=1e-6)
    assert abs(line @ sigma @ line) < 1e-9 * (line @ line) * np.trace(sigma)

    focal = centre_calibration_cov(replace(spec, calib_focal_error=0.02), K, T_world_cam)
    axis = T_world_cam[:3, 2]
    np.testing.assert_allclose(focal, (0.02 * z0) ** 2 * np.outer(axis, axis), atol=1e-12)
    assert centre_calibration_cov(spec, K, T_world_cam) is None  # the defaults: none
