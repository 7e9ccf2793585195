"""The sensor model every camera of every env shares (envs/sensor.py, envs/camera_rig.py):
latency delivers old frames exactly, calibration error moves the real camera away from
the calibration ``info`` reports, image noise reaches every env's pixels."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium.utils.env_checker import data_equivalence

import observer_gym.envs
from observer_gym.envs.ball_table.geometry import TABLE_CORNERS_TABLE
from observer_gym.envs.camera import PinholeIntrinsics, project_points
from observer_gym.envs.target_follower.geometry import image_state

ENV_IDS = observer_gym.envs.ENV_IDS
OBS_MODES = ("rgb", "state", "measurements")
SMALL_IMAGE = {"image_width_px": 80, "image_height_px": 60}
# TargetFollower's focal length is in pixels: a quarter-size image needs a quarter of it.
SMALL = {
    "observer_gym/BallTable-v0": SMALL_IMAGE,
    "observer_gym/BallCatcher-v1": SMALL_IMAGE,
    "observer_gym/TargetFollower-v0": {**SMALL_IMAGE, "fx_px": 98.35, "fy_px": 97.95},
}
# A latency that is not a whole number of env steps or frame periods, per env.
LATENCY_S = {
    "observer_gym/BallTable-v0": 0.05,  # 2.5 steps of 20 ms
    "observer_gym/BallCatcher-v1": 0.033,  # 3.3 steps of 10 ms, 1.65 frame periods
    "observer_gym/TargetFollower-v0": 0.25,  # 2.5 steps of 100 ms
}
STEPS = {
    "observer_gym/BallTable-v0": 12,
    "observer_gym/BallCatcher-v1": 14,
    "observer_gym/TargetFollower-v0": 8,
}


def _payload(env_id: str, obs, frame: dict):
    """What a delivered frame holds, read from public outputs: the observation of a
    one-camera env, the frame's own entry for BallCatcher's several cameras."""
    if env_id == "observer_gym/BallCatcher-v1":
        return frame.get("image", frame.get("uv_px"))
    return obs


def _run(make_env, env_id: str, obs_mode: str, latency_s: float):
    """Per step: the observation and the delivered frames, under open-loop actions."""
    env = make_env(env_id, obs_mode=obs_mode, latency_s=latency_s, **SMALL[env_id])
    rng = np.random.default_rng(5)
    obs, info = env.reset(seed=11)
    steps = [(obs, info)]
    for _ in range(STEPS[env_id]):
        action = rng.uniform(-0.3, 0.3, env.action_space.shape) * env.action_space.high
        obs, _, terminated, truncated, info = env.step(action.astype(np.float32))
        steps.append((obs, info))
        assert not (terminated or truncated)
    return env, steps


@pytest.mark.parametrize("obs_mode", OBS_MODES)
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_latency_delivers_the_frame_captured_latency_earlier(make_env, env_id, obs_mode):
    latency_s = LATENCY_S[env_id]
    env, prompt = _run(make_env, env_id, obs_mode, 0.0)
    _, late = _run(make_env, env_id, obs_mode, latency_s)
    dt_s = env.unwrapped.dt_s
    # Every frame of the prompt env, by camera and capture time (it delivers at capture).
    captured = {}
    for obs, info in prompt:
        for frame in info["frames"]:
            assert frame["delivery_time_s"] == pytest.approx(frame["capture_time_s"])
            key = (frame["camera_id"], round(frame["capture_time_s"], 9))
            captured[key] = _payload(env_id, obs, frame)
    newest: dict[int, float] = {}
    checked = 0
    for k, (obs, info) in enumerate(late):
        for frame in info["frames"]:
            camera, t = frame["camera_id"], frame["capture_time_s"]
            assert frame["delivery_time_s"] - t >= latency_s - 1e-9
            newest[camera] = max(newest.get(camera, -1.0), t)
            expected = captured[(camera, round(t, 9))]
            if obs_mode != "state":
                assert data_equivalence(_payload(env_id, obs, frame), expected)
        # The newest frame by step k is the last capture at or before k dt - L.
        for camera in {c for c, _ in captured}:
            times = [t for c, t in captured if c == camera and t <= k * dt_s - latency_s + 1e-9]
            if times:
                assert newest[camera] == pytest.approx(max(times), abs=1e-9)
                checked += 1
            else:
                assert camera not in newest
        if obs_mode != "state" and env_id != "observer_gym/BallCatcher-v1" and newest:
            # The one-camera envs observe the newest delivered frame.
            assert data_equivalence(obs, captured[(0, round(newest[0], 9))])
    assert checked >= STEPS[env_id] // 2


def _calibration_errors(draw: str) -> dict:
    return {
        "calib_focal_error": 0.03,
        "calib_principal_point_error_px": 4.0,
        "calib_rotation_error_deg": 1.0,
        "calib_translation_error_m": 0.01,
        "calib_error_draw": draw,
    }


def _projected_truth(env_id: str, info: dict, K: np.ndarray, T_world_cam: np.ndarray):
    """The perfect detector's report computed from the simulator's ground truth."""
    if env_id == "observer_gym/BallTable-v0":
        T = info["T_world_table"]
        corners = TABLE_CORNERS_TABLE @ T[:3, :3].T + T[:3, 3]
        return project_points(K, T_world_cam, corners)[0].reshape(-1)
    if env_id == "observer_gym/BallCatcher-v1":
        return project_points(K, T_world_cam, info["state"][None, :3])[0][0]
    return image_state(K, T_world_cam, info["target_pos_world"], 0.12)


def _measured(env_id: str, obs, frame: dict):
    if env_id == "observer_gym/BallTable-v0":
        return obs["table_corners_px"]
    if env_id == "observer_gym/BallCatcher-v1":
        return frame["uv_px"]
    return obs["target_px"]


EXACT = {"measurement_noise_px": 0.0}
TARGET_FOLLOWER_EXACT = {"measurement_rounding": False}


@pytest.mark.parametrize("draw", ["fixed", "per_episode"])
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_calibration_error_measures_through_the_true_camera(make_env, env_id, draw):
    extra = TARGET_FOLLOWER_EXACT if env_id == "observer_gym/TargetFollower-v0" else {}
    env = make_env(env_id, obs_mode="measurements", **EXACT, **extra, **_calibration_errors(draw))
    nominal = env.unwrapped.rig.nominal[0]
    compared = 0
    for seed in (0, 1):
        obs, info = env.reset(seed=seed)
        for _ in range(6):
            for frame, truth in zip(info["frames"], info["truth"]["frames"], strict=True):
                if env_id == "observer_gym/BallCatcher-v1" and frame["uv_px"] is None:
                    continue  # the ball is not in this camera's image yet
                # info reports the nominal calibration; the truth differs by the errors.
                np.testing.assert_array_equal(frame["K"], nominal.K)
                f_ratio = truth["K"][0, 0] / nominal.fx_px
                assert abs(f_ratio - 1.0) == pytest.approx(0.03)
                offset = truth["K"][:2, 2] - [nominal.cx_px, nominal.cy_px]
                assert np.linalg.norm(offset) == pytest.approx(4.0)
                moved = truth["T_world_cam"][:3, 3] - frame["T_world_cam"][:3, 3]
                assert np.linalg.norm(moved) == pytest.approx(0.01)
                measured = _measured(env_id, obs, frame)
                true = _projected_truth(env_id, info, truth["K"], truth["T_world_cam"])
                believed = _projected_truth(env_id, info, frame["K"], frame["T_world_cam"])
                np.testing.assert_allclose(measured, true, atol=1e-3)
                assert np.max(np.abs(np.asarray(believed) - true)) > 1.0  # it matters
                compared += 1
            obs, _, _, _, info = env.step(np.zeros(env.action_space.shape, np.float32))
    assert compared >= 6


def test_per_episode_calibration_errors_change_with_the_seed(make_env):
    env = make_env(
        "observer_gym/BallTable-v0", obs_mode="state", **_calibration_errors("per_episode")
    )
    poses = []
    for seed in (0, 1, 0):
        _, info = env.reset(seed=seed)
        poses.append(info["truth"]["frames"][0]["T_world_cam"])
    assert not np.allclose(poses[0], poses[1])
    np.testing.assert_array_equal(poses[0], poses[2])


def test_the_calibration_error_rotates_by_its_size(make_env):
    env = make_env("observer_gym/BallTable-v0", obs_mode="state", calib_rotation_error_deg=2.0)
    _, info = env.reset(seed=3)
    R_nominal = info["frames"][0]["T_world_cam"][:3, :3]
    R_true = info["truth"]["frames"][0]["T_world_cam"][:3, :3]
    cos_angle = (np.trace(R_nominal.T @ R_true) - 1.0) / 2.0
    assert np.degrees(np.arccos(cos_angle)) == pytest.approx(2.0)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_image_noise_reaches_every_envs_pixels(make_env, env_id):
    clean = make_env(env_id, obs_mode="rgb", **SMALL[env_id])
    noisy = make_env(env_id, obs_mode="rgb", image_noise_std=8.0, **SMALL[env_id])
    obs_clean, _ = clean.reset(seed=2)
    obs_noisy, _ = noisy.reset(seed=2)
    if isinstance(obs_clean, dict):  # BallCatcher: one image per camera
        obs_clean, obs_noisy = obs_clean["camera_0"], obs_noisy["camera_0"]
    difference = obs_noisy.astype(float) - obs_clean
    # What N(0, 8^2) noise, rounded and clipped to 0-255, does to this clean image.
    simulated = np.random.default_rng(0).normal(0.0, 8.0, obs_clean.shape)
    expected = np.clip(np.rint(obs_clean + simulated), 0, 255) - obs_clean
    assert np.mean(difference != 0) > 0.3
    assert np.std(difference) == pytest.approx(np.std(expected), rel=0.05)
    assert np.mean(difference) == pytest.approx(np.mean(expected), abs=0.1)


def test_frame_phase_must_stay_within_a_frame_period(make_env):
    with pytest.raises(ValueError, match=r"frame_phase_s=0\.02 must be below one frame period"):
        make_env("observer_gym/BallTable-v0", frame_phase_s=0.02)


def test_a_phase_captures_between_steps(make_env):
    env = make_env("observer_gym/BallTable-v0", obs_mode="state", frame_phase_s=0.012)
    _, info = env.reset(seed=0)
    assert info["frames"] == []  # nothing captured at reset's tick
    times = []
    for _ in range(3):
        *_, info = env.step(np.zeros(2, np.float32))
        times += [f["capture_time_s"] for f in info["frames"]]
    # 250 Hz physics: 0.012 s is tick 3; then every 20 ms.
    np.testing.assert_allclose(times, [0.012, 0.032, 0.052], atol=1e-12)


def test_intrinsics_of_the_true_camera_scale_and_shift():
    from observer_gym.envs.camera_rig import CalibrationError

    nominal = PinholeIntrinsics.from_fov(320, 240, 90.0)
    true = CalibrationError(1.05, (2.0, -3.0)).true_intrinsics(nominal)
    expected = (168.0, 168.0, 162.0, 117.0)
    assert (true.fx_px, true.fy_px, true.cx_px, true.cy_px) == pytest.approx(expected)
