"""TargetFollower-v0 against the spec's kinematics, target profile (44), noise model and
drive, and the simulator's own geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from observer_gym.envs.target_follower import (
    APPLIED,
    DETECTED,
    IMAGE,
    IMAGE_RATE,
    TARGET_PX,
    StateIndex,
    TargetFollowerConfig,
)
from observer_gym.envs.target_follower import geometry as geo
from observer_gym.envs.target_follower.drive import DriveLimits, applied_wheel_speeds

ENV_ID = "observer_gym/TargetFollower-v0"
T_S = 0.1
STILL = np.zeros(3, np.float32)


def test_profile_44_velocity_and_position(make_env):
    env = make_env(ENV_ID, obs_mode="state", target_motion="profile")
    _, info = env.reset(seed=0, options={"target_pos_world_m": (2.0, 0.0, 1.4)})
    start = info["target_pos_world"]
    for n in range(1, 151):
        _, _, _, _, info = env.step(STILL)
        t = n * T_S
        speed = 0.15 * math.cos(n * math.pi * T_S / 20.0)  # (44)
        heading = n * T_S * 5.0 * math.pi / 72.0  # (44): theta_t(n) = theta_t(n-1) + T 5 pi/72
        np.testing.assert_allclose(
            info["target_vel_world"],
            [speed * math.cos(heading), speed * math.sin(heading), 0.0],
            atol=1e-12,
        )
    # Position: the integral of the velocity, by a fine trapezoid.
    ts = np.linspace(0.0, t, 150_001)
    v = 0.15 * np.cos(np.pi * ts / 20.0)
    h = 5.0 * np.pi / 72.0 * ts
    expected = start[:2] + np.array(
        [np.trapezoid(v * np.cos(h), ts), np.trapezoid(v * np.sin(h), ts)]
    )
    np.testing.assert_allclose(info["target_pos_world"][:2], expected, atol=1e-6)


def test_profile_without_turning_goes_back_and_forth_on_a_line(make_env):
    # profile_turn_rate_radps = 0: (44)'s speed along a fixed heading, here the start's.
    env = make_env(ENV_ID, obs_mode="state", target_motion="profile", profile_turn_rate_radps=0.0)
    _, info = env.reset(seed=0, options={"target_pos_world_m": (2.0, 0.0, 1.4)})
    start = info["target_pos_world"].copy()
    for n in range(1, 401):
        _, _, _, _, info = env.step(STILL)
        speed = 0.15 * math.cos(n * math.pi * T_S / 20.0)  # (44)
        np.testing.assert_allclose(info["target_vel_world"], [speed, 0.0, 0.0], atol=1e-12)
    # One period of v_t: the integral of 0.15 cos(pi t / 20) over 40 s is 0.
    np.testing.assert_allclose(info["target_pos_world"], start, atol=1e-9)


def test_state_rates_are_the_time_derivative_of_the_image_state(make_env):
    # With the robot still, X_i' is all target-induced: J_t V_t of the state must equal the
    # central difference of the image state over +-T.
    env = make_env(ENV_ID, obs_mode="state", target_motion="profile")
    _, info = env.reset(seed=3)
    states = [info["state"]]
    for _ in range(40):
        states.append(env.step(STILL)[4]["state"])
    states = np.array(states)
    central = (states[2:, IMAGE] - states[:-2, IMAGE]) / (2 * T_S)
    rates = states[1:-1, IMAGE_RATE]
    # The central difference is exact to O(T^2) on the smooth profile (44).
    scale = np.abs(rates).max(axis=0)
    assert np.all(np.abs(central - rates).max(axis=0) <= 0.01 * scale)


def test_robot_follows_the_unicycle_exactly(make_env):
    env = make_env(ENV_ID, obs_mode="state", target_motion="static")
    env.reset(seed=0)
    v, omega, omega_t = 0.3, 0.5, 0.2
    for _ in range(20):
        _, _, _, _, info = env.step(np.array([v, omega, omega_t], np.float32))
    t = 2.0
    state = info["state"]
    v32, w32, wt32 = (float(np.float32(a)) for a in (v, omega, omega_t))
    np.testing.assert_allclose(
        state[StateIndex.ROBOT_X : StateIndex.ROBOT_YAW + 1],
        [v32 / w32 * math.sin(w32 * t), v32 / w32 * (1 - math.cos(w32 * t)), w32 * t],
        atol=1e-9,
    )
    assert state[StateIndex.TILT] == pytest.approx(wt32 * t, abs=1e-9)
    np.testing.assert_allclose(state[APPLIED], [v32, w32, wt32], atol=1e-12)
    # The camera pose is the robot's, and robot_pose_from_camera inverts it.
    T = info["camera"]["T_world_cam"]
    xy, yaw, tilt = geo.robot_pose_from_camera(T, 0.10)
    np.testing.assert_allclose([*xy, yaw, tilt], state[StateIndex.ROBOT_X : StateIndex.TILT + 1])


def test_tilt_stops_at_its_limits(make_env):
    env = make_env(ENV_ID, obs_mode="state", target_motion="static", tilt_max_rad=0.3)
    env.reset(seed=0)
    for _ in range(10):
        _, _, _, _, info = env.step(np.array([0.0, 0.0, 1.0], np.float32))
    assert info["state"][StateIndex.TILT] == pytest.approx(0.3)
    assert info["applied_action"][2] == 0.0  # the platform is at its end stop


def _camera_pose_by_matrix_products(robot_xy_m, yaw_rad, tilt_rad, delta_y_m):
    """geo.camera_pose with R_base_cam by np.column_stack, as it was built before."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    ct, st = math.cos(tilt_rad), math.sin(tilt_rad)
    forward_base = np.array([ct, 0.0, st])
    up_base = np.array([-st, 0.0, ct])
    right_base = np.array([0.0, -1.0, 0.0])
    R_world_base = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    R_base_cam = np.column_stack([right_base, -up_base, forward_base])
    centre_base = geo.TILT_AXIS_BASE_M + delta_y_m * up_base
    centre_world = R_world_base @ centre_base + np.array([robot_xy_m[0], robot_xy_m[1], 0.0])
    T = np.eye(4)
    T[:3, :3] = R_world_base @ R_base_cam
    T[:3, 3] = centre_world
    return T


def test_camera_pose_equals_the_matrix_products_bit_for_bit():
    rng = np.random.default_rng(0)
    special = [0.0, -0.0, math.pi / 2, -math.pi / 2, math.pi, 1e-300, -1e-300]
    cases = [
        (rng.normal(size=2) * 3, *rng.uniform(-4, 4, 2), rng.uniform(0, 0.5)) for _ in range(20000)
    ]
    cases += [
        (np.array([x, -x]), yaw, tilt, d)
        for x in (0.0, -0.0, 1.5)
        for yaw in special
        for tilt in special
        for d in (0.0, 0.1)
    ]
    for xy, yaw, tilt, delta_y in cases:
        expected = _camera_pose_by_matrix_products(xy, yaw, tilt, delta_y)
        assert geo.camera_pose(xy, yaw, tilt, delta_y).tobytes() == expected.tobytes()


def test_wheel_quantisation_floors_to_whole_cm_per_s():
    limits = DriveLimits(wheel_base_m=0.4, quantize=True)
    # v_l = 0.1 - 0.33 * 0.2 = 0.034 -> 0.03; v_r = 0.166 -> 0.16 (floor, 8-bit cm/s)
    wheels = applied_wheel_speeds(0.1, 0.33, np.zeros(2), T_S, limits)
    np.testing.assert_allclose(wheels, [0.03, 0.16])
    wheels = applied_wheel_speeds(-0.1, 0.0, np.zeros(2), T_S, limits)  # floor goes down
    np.testing.assert_allclose(wheels, [-0.10, -0.10])
    wheels = applied_wheel_speeds(-0.105, 0.0, np.zeros(2), T_S, limits)
    np.testing.assert_allclose(wheels, [-0.11, -0.11])
    wheels = applied_wheel_speeds(2.0, 0.0, np.zeros(2), T_S, DriveLimits(5.0, 5.0, 0.0, True))
    np.testing.assert_allclose(wheels, [1.27, 1.27])  # 127 cm/s: the 8-bit limit


def test_velocity_and_acceleration_scaling_keep_the_turning_radius():
    limits = DriveLimits(wheel_base_m=0.4, wheel_speed_max_mps=0.5, wheel_accel_max_mps2=1.0)
    wheels = applied_wheel_speeds(0.6, 1.0, np.array([0.3, 0.3]), T_S, limits)
    # Commanded (0.4, 0.8) -> scaled to (0.25, 0.5); the change from (0.3, 0.3) is
    # (-0.05, 0.2), above 1 m/s^2 * 0.1 s: scaled by 0.1 / 0.2.
    np.testing.assert_allclose(wheels, [0.3 - 0.025, 0.3 + 0.1])


def test_env_applies_quantised_speeds(make_env):
    env = make_env(ENV_ID, obs_mode="state", target_motion="static", wheel_quantization=True)
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([0.1, 0.33, 0.0], np.float32))
    np.testing.assert_allclose(info["applied_action"][:2], [0.095, 0.325], atol=1e-9)


@pytest.mark.parametrize("sigma", [0.0, 4.0])
def test_measurement_noise_model(make_env, sigma):
    # Z = round(X + sigma (2 w - 1)), w ~ U[0, 1]: integer, within sigma + 1/2 of X, with
    # the variance sigma^2 / 3 (+ 1/12 from the rounding).
    env = make_env(
        ENV_ID, obs_mode="measurements", target_motion="profile", measurement_noise_px=sigma
    )
    obs, info = env.reset(seed=0)
    errors = []
    for _ in range(150):  # the target walks off to the side, still in view at 15 s
        assert obs[DETECTED][0] == 1
        z = obs[TARGET_PX].astype(float)
        np.testing.assert_array_equal(z, np.round(z))
        errors.append(z - info["state"][IMAGE])
        obs, _, _, _, info = env.step(STILL)
    errors = np.array(errors)
    assert np.abs(errors).max() <= sigma + 0.5 + 1e-9
    expected_var = sigma**2 / 3.0 + 1.0 / 12.0
    np.testing.assert_allclose(errors.var(axis=0), expected_var, rtol=0.2)


def test_occluder_hides_the_target_for_its_hold_time(make_env):
    env = make_env(ENV_ID, obs_mode="measurements", target_motion="static", occluder_hold_s=3.0)
    obs, info = env.reset(seed=0, options={"occlusions_s": (1.0,)})
    seen = []
    for _ in range(70):
        obs, _, _, _, info = env.step(STILL)
        seen.append((round(info["time_s"], 6), int(obs[DETECTED][0]), info["occluded"]))
        assert info["state"][StateIndex.TARGET_VISIBLE] == obs[DETECTED][0]
    hidden = {t for t, detected, _ in seen if not detected}
    # It walks in for 1 s from t = 1 s, hides the target from 2 s to 5 s, walks out.
    assert {round(2.0 + 0.1 * k, 6) for k in range(31)} <= hidden
    assert 1.0 < min(hidden) and max(hidden) < 6.0
    assert all(detected == (not occluded) for _, detected, occluded in seen)
    assert seen[-1][1] == 1  # visible again


def test_rendered_target_is_where_the_state_says(make_env):
    from observer_gym.estimation.target_follower.detector import TargetFollowerDetector

    env = make_env(ENV_ID, obs_mode="rgb", target_motion="static")
    detector = TargetFollowerDetector()
    for seed in range(5):
        obs, info = env.reset(seed=seed)
        z = detector.detect(obs, info["camera"]["K"])
        np.testing.assert_allclose(z[:2], info["state"][:2], atol=0.5)


def test_occluded_frame_shows_no_target(make_env):
    from observer_gym.estimation.target_follower.detector import TargetFollowerDetector

    env = make_env(ENV_ID, obs_mode="rgb", target_motion="static")
    env.reset(seed=1, options={"occlusions_s": (0.0,)})
    for _ in range(20):
        obs, _, _, _, info = env.step(STILL)
    assert info["occluded"]
    assert TargetFollowerDetector().detect(obs, info["camera"]["K"]) is None


def test_lost_target_terminates_after_the_timeout(make_env):
    env = make_env(ENV_ID, obs_mode="state", target_motion="static", lost_timeout_s=1.0)
    env.reset(seed=0)
    steps = 0
    terminated = False
    while not terminated:
        _, reward, terminated, _, info = env.step(np.array([0.0, 1.0, 0.0], np.float32))
        steps += 1
        assert steps < 100
    assert not info["target_in_image"] and reward == 0.0


def test_reward_is_one_at_the_set_point(make_env):
    env = make_env(ENV_ID, obs_mode="state", target_motion="static")
    eye = geo.camera_pose(np.zeros(2), 0.0, 0.0, 0.10)[:3, 3]
    depth = 393.4 * 0.12 / 35.0  # d_x = f_x W / z_c = 35 px
    env.reset(seed=0, options={"target_pos_world_m": eye + np.array([depth, 0.0, 0.0])})
    _, reward, *_ = env.step(STILL)
    assert reward == pytest.approx(1.0, abs=1e-9)


@pytest.mark.parametrize(
    ("name", "value", "allowed"),
    [
        ("target_motion", "spiral", "choose one of ['random_walk', 'profile', 'static']"),
        ("fx_px", 0.0, "out of range; allowed: [20.0, 5000.0]"),
        ("wheel_quantization", 1, "must be True or False"),
    ],
)
def test_bad_config_values_name_the_field(name, value, allowed):
    with pytest.raises(ValueError, match=f"^{name}=") as excinfo:
        TargetFollowerConfig(**{name: value})
    assert allowed in str(excinfo.value)


def test_inverted_start_ranges_are_rejected():
    with pytest.raises(ValueError, match=r"start_distance_min_m=2\.0 must not exceed"):
        TargetFollowerConfig(start_distance_min_m=2.0, start_distance_max_m=1.0)


def test_unknown_reset_option_is_rejected(make_env):
    env = make_env(ENV_ID, obs_mode="state")
    with pytest.raises(ValueError, match="unknown reset options"):
        env.reset(seed=0, options={"ball_pos": (0, 0)})
