"""The visual tracking controller (docs/spec/follower.md (5)-(19)) in closed loop on
TargetFollower-v0: exponential error decay per channel at the gains of Table 1, the
dual-Jacobian feedforward, the singularity stop and the design from the env."""

from __future__ import annotations

import math

import numpy as np
import pytest

from observer_gym.controllers import make_controller
from observer_gym.controllers.target_follower.plant import TargetFollowerPlant
from observer_gym.controllers.target_follower.vtc import SIMULATION_GAINS, VisualTrackingController
from observer_gym.envs.target_follower import IMAGE, STATE_DIM, StateIndex
from observer_gym.envs.target_follower import geometry as geo
from observer_gym.estimation.target_follower.models import (
    TargetFollowerCameraParams,
    robot_jacobian,
    singularity_margin,
)

ENV_ID = "observer_gym/TargetFollower-v0"
T_S = 0.1
DESIRED = np.array([0.0, 0.0, 35.0])


def _offset_target(x_i, y_i, d_x):
    """World position of a target that images at (x_i, y_i, d_x) from the start pose."""
    T = geo.camera_pose(np.zeros(2), 0.0, 0.0, 0.10)
    z = 393.4 * 0.12 / d_x
    p_cam = np.array([x_i * z / 393.4, -y_i * z / 391.8, z])
    return T[:3, :3] @ p_cam + T[:3, 3]


def test_error_decays_as_exp_minus_alpha_t_per_channel(make_env):
    env = make_env(ENV_ID, obs_mode="state", target_motion="static")
    controller = make_controller("vtc", env)
    obs, info = env.reset(seed=0, options={"target_pos_world_m": _offset_target(40, -25, 28)})
    errors = [info["state"][IMAGE] - DESIRED]
    for _ in range(40):
        action, _ = controller.predict(obs)
        assert np.all(np.abs(action) < env.action_space.high)  # no saturation here
        obs, _, _, _, info = env.step(action)
        errors.append(info["state"][IMAGE] - DESIRED)
    errors = np.array(errors)
    t = T_S * np.arange(len(errors))
    rates = []
    for j, alpha in enumerate(SIMULATION_GAINS):
        slope, _ = np.polyfit(t, np.log(np.abs(errors[:, j])), 1)
        rates.append(-slope)
        # Sampled with the command held over T, the exact decay per sample is 1 - alpha T.
        discrete = -math.log(1.0 - alpha * T_S) / T_S
        assert -slope == pytest.approx(discrete, rel=0.01)
        assert -slope == pytest.approx(alpha, rel=0.05)
    print(f"\ndecay rates {np.round(rates, 4)} 1/s for alpha = {np.round(SIMULATION_GAINS, 4)}")


def test_feedforward_of_the_target_image_velocity_tracks_a_moving_target(make_env):
    # Oracle state, target moving by (44): with X_i^t' fed forward (13) the error stays
    # well below what the feedback alone leaves.
    rms = {}
    for feedforward in (True, False):
        env = make_env(ENV_ID, obs_mode="state", target_motion="profile")
        controller = make_controller("vtc", env)
        obs, info = env.reset(seed=2)
        errors = []
        for n in range(300):
            if not feedforward:
                obs = obs.copy()
                obs[StateIndex.X_I_RATE : StateIndex.D_X_RATE + 1] = 0.0
            action, _ = controller.predict(obs)
            obs, _, terminated, _, info = env.step(action)
            assert not terminated
            if n >= 100:
                errors.append(info["state"][IMAGE] - DESIRED)
        rms[feedforward] = np.sqrt(np.mean(np.square(errors), axis=0))
    print(f"\nRMS image error 10-30 s: with feedforward {rms[True]}, without {rms[False]}")
    assert np.all(rms[True] < 1.0)
    assert np.all(rms[True] < 0.2 * rms[False])


def _plant():
    return TargetFollowerPlant(
        camera=_camera(),
        desired_px=(0.0, 0.0, 35.0),
        dt_s=T_S,
        action_low=-np.array([0.6, 1.0, 1.0]),
        action_high=np.array([0.6, 1.0, 1.0]),
        obs_dim=STATE_DIM,
    )


def _camera():
    return TargetFollowerCameraParams()  # Table 1


def _obs(X_i, rates=(0.0, 0.0, 0.0), tilt=0.0, valid=1.0):
    obs = np.zeros(STATE_DIM)
    obs[IMAGE] = X_i
    obs[StateIndex.X_I_RATE : StateIndex.D_X_RATE + 1] = rates
    obs[StateIndex.TILT] = tilt
    obs[StateIndex.TRACKING_VALID] = valid
    return obs


def test_law_13_in_one_step():
    controller = VisualTrackingController(_plant())
    X_i, rates, tilt = np.array([20.0, -10.0, 30.0]), np.array([5.0, -3.0, 1.0]), 0.2
    action, _ = controller.predict(_obs(X_i, rates, tilt))
    B = robot_jacobian(X_i, tilt, _camera())
    # B u = K_g X_e - X_i^t' (13), with X_e = X* - X_i
    np.testing.assert_allclose(
        B @ action, np.diag(SIMULATION_GAINS) @ (DESIRED - X_i) - rates, rtol=1e-5
    )


def test_saturated_command_keeps_its_direction():
    controller = VisualTrackingController(_plant())
    X_i, tilt = np.array([150.0, 100.0, 5.0]), 0.1
    action, _ = controller.predict(_obs(X_i, tilt=tilt))
    u = controller.command(X_i, np.zeros(3), tilt)
    assert np.max(np.abs(action) / controller.action_high) == pytest.approx(1.0, rel=1e-6)
    np.testing.assert_allclose(action / np.linalg.norm(action), u / np.linalg.norm(u), rtol=1e-5)


def test_stops_at_the_singularity_and_when_tracking_is_invalid():
    controller = VisualTrackingController(_plant())
    camera = _camera()
    tilt, d_x = 0.9, 30.0
    S = camera.fy_px * camera.delta_y_m / (camera.fx_px * camera.target_width_m)
    singular = np.array([5.0, camera.fy_px / math.tan(tilt) - S * d_x + 2.0, d_x])
    assert abs(singularity_margin(singular, tilt, camera)) < controller.singular_margin_px
    action, _ = controller.predict(_obs(singular, tilt=tilt))
    np.testing.assert_array_equal(action, np.zeros(3))
    action, _ = controller.predict(_obs([30.0, 0.0, 20.0], valid=0.0))
    np.testing.assert_array_equal(action, np.zeros(3))
    assert controller.stops == 2


def test_vtc_is_designed_only_for_target_follower(make_env):
    with pytest.raises(ValueError, match="TargetFollower"):
        make_controller("vtc", make_env("observer_gym/BallTable-v0", obs_mode="state"))
    with pytest.raises(ValueError, match="gains"):
        VisualTrackingController(_plant(), gains=(0.5, -1.0, 0.3))
