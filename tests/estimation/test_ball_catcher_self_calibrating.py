"""BallCatcher's self-calibrating observers (``selfcal``, ``endpoint``) and the env's hole
reports they read (issue 41): the hole's pixels are the real camera's projection of the
hole, the ball relative to the hole moves with a camera's error as the closed form says,
a camera's error is recovered from throws, the covariances hold, bad input is refused."""

from __future__ import annotations

import numpy as np
import pytest
from consistency_cells import CONDITIONS, HIGH, LOW, median_nees

from observer_gym.controllers import make_controller
from observer_gym.envs import system_for_id
from observer_gym.envs.ball_catcher import geometry as geo
from observer_gym.envs.camera import project_points
from observer_gym.estimation import VisionObserver
from observer_gym.estimation.ball_catcher import EndpointObserver, SelfCalibratingObserver
from observer_gym.estimation.ball_catcher.self_calibrating import BoxTrack
from observer_gym.estimation.calibration import moved_camera
from observer_gym.train.core.observer_env import make_env as make_observer_env
from observer_gym.train.core.observer_env import resolve_observer
from observer_gym.train.experiments.benchmark.suite import load_suite

ENV_ID = "observer_gym/BallCatcher-v1"
# suite v1's lab and field levels
LAB = load_suite("BallCatcher-v1", "v1").level("lab").env_options
FIELD = load_suite("BallCatcher-v1", "v1").level("field").env_options
ROTATION_ONLY = {"rotation": 1.0}  # moved_camera's parameters: a rotation about x, y, z


# --- the env's hole reports ---------------------------------------------------------------


def test_the_hole_report_is_the_real_cameras_projection_of_the_hole(make_env):
    """Noise-free, with every calibration error: each reported hole pixel is the hole's
    centre (the box at rest at its home) through the frame's true camera, and only
    camera 1 has it in view at the default placement."""
    env = make_env(
        ENV_ID,
        obs_mode="measurements",
        hole_measurements=True,
        measurement_noise_px=0.0,
        calib_principal_point_error_px=3.0,
        calib_rotation_error_deg=0.3,
    )
    env.reset(seed=4)
    seen = set()
    for _ in range(5):  # the box stands still: the zero command
        _, _, _, _, info = env.step(np.zeros(3, np.float32))
        hole = info["T_world_box"][:3, 3]
        for frame, true in zip(info["frames"], info["truth"]["frames"], strict=True):
            uv, _ = project_points(true["K"], true["T_world_cam"], hole[None])
            if frame["hole_uv_px"] is None:
                continue
            seen.add(frame["camera_id"])
            np.testing.assert_allclose(frame["hole_uv_px"], uv[0], atol=1e-9)
            nominal, _ = project_points(frame["K"], frame["T_world_cam"], hole[None])
            assert np.linalg.norm(frame["hole_uv_px"] - nominal[0]) > 0.5  # the error shows
    assert seen == {1}


def test_the_hole_reports_leave_the_balls_noise_as_it_was(make_env):
    observations = []
    for holes in (False, True):
        env = make_env(
            ENV_ID, obs_mode="measurements", hole_measurements=holes, measurement_noise_px=1.0
        )
        obs, _ = env.reset(seed=11)
        for _ in range(8):
            obs, *_ = env.step(np.zeros(3, np.float32))
        observations.append(obs)
        assert env.observation_space.contains(obs)
    plain, with_holes = observations
    np.testing.assert_array_equal(plain["uv_px"], with_holes["uv_px"])
    assert "hole_uv_px" not in plain and with_holes["hole_detected"].tolist() == [0, 1]


# --- the endpoint's closed form -------------------------------------------------------------


def _pixels(K, T, points):
    uv, depth = project_points(K, T, np.asarray(points, dtype=float))
    assert np.all(depth > 0)
    return uv


def test_ball_relative_to_hole_against_the_closed_form(make_env):
    """Camera 1 (nominal), the hole at its home and the ball 5 cm in front of it, a bit
    off the axis. A principal-point offset moves both pixels alike: their difference not
    at all. A rotation w about the camera's y axis moves a pixel with normalised
    coordinates (x, y) by (-f (1 + x^2), -f x y) w to first order, so the difference by
    (-f (x_b^2 - x_h^2), -f (x_b y_b - x_h y_h)) w: checked against central differences,
    and far smaller than each pixel's own move."""
    env = make_env(ENV_ID, obs_mode="measurements")
    env.reset(seed=0)
    K = env.unwrapped.camera_intrinsics()[1].K
    T = geo.camera_pose(1)
    hole = geo.HOLE_HOME_WORLD
    ball = hole + np.array([0.05, 0.02, 0.03])
    f, cx, cy = K[0, 0], K[0, 2], K[1, 2]

    shifted = K.copy()
    shifted[:2, 2] += (0.7, -0.4)
    before, after = _pixels(K, T, [ball, hole]), _pixels(shifted, T, [ball, hole])
    np.testing.assert_allclose(after - before, [[0.7, -0.4], [0.7, -0.4]], atol=1e-12)
    np.testing.assert_allclose((after[0] - after[1]) - (before[0] - before[1]), 0.0, atol=1e-12)

    w = 1e-5
    plus = _pixels(*moved_camera(K, T, ROTATION_ONLY, np.array([0.0, w, 0.0])), [ball, hole])
    minus = _pixels(*moved_camera(K, T, ROTATION_ONLY, np.array([0.0, -w, 0.0])), [ball, hole])
    d_each = (plus - minus) / (2 * w)  # d(pixel)/dw of the ball and the hole
    d_relative = d_each[0] - d_each[1]
    (xb, yb), (xh, yh) = ((before - (cx, cy)) / f).tolist()
    closed_form = [-f * (xb**2 - xh**2), -f * (xb * yb - xh * yh)]
    np.testing.assert_allclose(d_relative, closed_form, rtol=1e-6, atol=1e-6 * f)
    np.testing.assert_allclose(d_each[1], [-f * (1 + xh**2), -f * xh * yh], rtol=1e-6)
    assert np.linalg.norm(d_relative) < 0.1 * np.linalg.norm(d_each[1])


# --- a camera's error recovered -------------------------------------------------------------


# Where each camera's error is judged: camera 1 at the hole's home; camera 0 along the mean
# throw's path, where it sees the ball (it does not see the box).
_PATH = np.linspace([3.2, 0.0, 0.55], [0.7, 0.0, 0.5], 25)
_PATH[:, 2] += 0.5 * 9.81 * 0.22**2 * (1 - np.linspace(-1, 1, 25) ** 2)
_POINTS = {0: _PATH, 1: geo.HOLE_HOME_WORLD[None]}


def _image_error_px(calibration, x_aug, frame, true_frame, camera):
    """(estimated, nominal): the mean distance between where the camera the filter
    estimates, and the nominal one, put the camera's points and where the real camera
    does (the points inside its image)."""
    c = calibration.offsets(x_aug)[camera]
    K, T = moved_camera(frame["K"], frame["T_world_cam"], calibration.variances, c)
    true, depth = project_points(true_frame["K"], true_frame["T_world_cam"], _POINTS[camera])
    w, h = frame["image_size_px"]
    seen = (depth > 0) & (true[:, 0] >= 0) & (true[:, 0] < w) & (true[:, 1] >= 0) & (true[:, 1] < h)
    assert seen.any()
    estimated, _ = project_points(K, T, _POINTS[camera][seen])
    nominal, _ = project_points(frame["K"], frame["T_world_cam"], _POINTS[camera][seen])
    return tuple(
        float(np.linalg.norm(uv - true[seen], axis=1).mean()) for uv in (estimated, nominal)
    )


def test_a_cameras_error_is_recovered_from_throws_and_carried_over(make_env):
    """One rig over consecutive throws (``calib_error_draw="fixed"``) at lab's errors and
    noise: camera 1, which sees the hole, is recovered to within 0.3 px at the hole (the
    nominal camera is off by 1.4 px there) after each throw, and to within 0.15 px once
    three throws have carried over; camera 0 (the ball its only evidence) ends every throw
    closer to its true camera along its view of the flight than the nominal one is (0.95
    px), and its carried prior is tighter than the declared one. Measured (seeds
    7000-7005): camera 1 0.08, 0.22, 0.25, 0.10, 0.02, 0.01 px; camera 0 0.59, 0.43, 0.47,
    0.41, 0.31, 0.49 px (benchmarks/ball_catcher_calibration.py --only-rig prints 20)."""
    env = make_env(
        ENV_ID, obs_mode="measurements", hole_measurements=True, calib_error_draw="fixed", **LAB
    )
    observer = EndpointObserver(env.unwrapped)
    assert observer.carry_over
    controller = make_controller("intercept", env)
    errors = []
    for seed in range(7000, 7006):
        obs, info = env.reset(seed=seed)
        observer.reset()
        controller.reset()
        action, frames = None, {}
        while True:
            for frame, true in zip(info["frames"], info["truth"]["frames"], strict=True):
                frames[frame["camera_id"]] = (frame, true)
            estimate = observer.observe(obs, info, action)
            controller.observe_info({"estimate": estimate.as_info()})
            command, _ = controller.predict(estimate.mean.astype(np.float32), deterministic=True)
            obs, _, terminated, truncated, info = env.step(command)
            action = info["applied_action"]
            if terminated or truncated:
                break
        x_aug = observer.estimate_in_flight()
        errors.append([_image_error_px(observer.parameters, x_aug, *frames[c], c) for c in (0, 1)])
    print("image error per throw, cameras 0 and 1 (estimated, nominal; px):", np.round(errors, 3))
    (camera_0, nominal_0), (camera_1, nominal_1) = np.array(errors).transpose(1, 2, 0)
    assert np.all(nominal_1 > 1.3) and np.all(nominal_0 > 0.9)
    assert camera_1.max() < 0.3 and camera_1[3:].max() < 0.15, camera_1
    assert np.all(camera_0 < nominal_0), camera_0
    m = observer.parameters.m  # camera 0's carried prior: tighter than the declared one
    declared = np.diag(observer.parameters._V)[:m]
    assert np.all(np.diag(observer.parameters.prior_cov)[:m] <= declared)
    assert np.diag(observer.parameters.prior_cov)[:m].sum() < 0.9 * declared.sum()


def test_box_track_interpolates_the_kinematics():
    track = BoxTrack()
    track.add({"time_s": 0.0, "box_pos_world_m": [0.7, 0.0, 0.5], "box_vel_world_mps": [0, 0, 0]})
    track.add({"time_s": 0.01, "box_pos_world_m": [0.7, 0.01, 0.5], "box_vel_world_mps": [0, 1, 0]})
    np.testing.assert_allclose(track.at(0.004), [0.7, 0.004, 0.5])
    np.testing.assert_allclose(track.at(0.012), [0.7, 0.012, 0.5])  # along the velocity
    np.testing.assert_allclose(track.at(-1.0), [0.7, 0.0, 0.5])


# --- covariances ------------------------------------------------------------------------------

CELLS = {
    **CONDITIONS,
    "lab": LAB,
    "lab-fixed": {**LAB, "calib_error_draw": "fixed"},
    "field": FIELD,
    "rotation-1deg": {"calib_rotation_error_deg": 1.0},
}


@pytest.mark.parametrize(
    ("condition", "observer"),
    [  # the lab and field levels in the default run; the other cells (0.3-0.8 s each idle) slow
        (condition, observer)
        if condition in ("lab", "field")
        else pytest.param(condition, observer, marks=pytest.mark.slow)
        for observer in ("selfcal", "endpoint")
        for condition in sorted(CELLS)
    ],
)
def test_median_nees_per_dof_over_the_flight_is_within_the_band(observer, condition):
    """As tests/estimation/test_consistency_ball_catcher.py's cells (3 throws, intercept on
    the observer's own estimate), for the self-calibrating observers, plus the suite's
    lab and field levels (lab's calibration errors also fixed over the throws)."""
    ratio = median_nees(ENV_ID, f"{observer}-measurements", "intercept", 3, None, CELLS[condition])
    assert LOW <= ratio <= HIGH, ratio


# --- bad input ---------------------------------------------------------------------------------


def test_endpoint_needs_the_hole_reports(make_env):
    env = make_env(ENV_ID, obs_mode="measurements", **LAB)
    with pytest.raises(ValueError, match="hole_measurements=True"):
        EndpointObserver(env.unwrapped)
    with pytest.raises(ValueError, match="hole_measurements"):
        VisionObserver(make_env(ENV_ID, obs_mode="rgb"), observer="endpoint")


def test_the_observers_env_option_travels_and_a_contradiction_is_refused():
    system = system_for_id(ENV_ID)
    endpoint = resolve_observer(system, "endpoint-measurements")
    env = make_observer_env(system, endpoint, LAB)
    try:
        assert env.unwrapped.config.hole_measurements is True
        assert "hole_uv_px" in env.unwrapped.observation_space.spaces
    finally:
        env.close()
    with pytest.raises(ValueError, match="needs the env option hole_measurements=True"):
        make_observer_env(system, endpoint, {"hole_measurements": False})


@pytest.mark.parametrize(
    ("options", "match"),
    [
        ({"landmarks": "yes"}, "landmarks"),
        ({"landmarks": 1}, "landmarks"),
        ({"carry_over": "always"}, "carry_over"),
        ({"carry_over": 1}, "carry_over"),
        ({"estimated": ("rotation", "warp")}, "estimated"),
        ({"estimated": "rotation"}, "estimated"),
    ],
)
def test_bad_options_are_refused(make_env, options, match):
    env = make_env(ENV_ID, obs_mode="measurements", **LAB)
    with pytest.raises(ValueError, match=match):
        SelfCalibratingObserver(env.unwrapped, **options)


@pytest.mark.parametrize("bad", ["x", 2, None])
def test_hole_measurements_must_be_a_bool(make_env, bad):
    with pytest.raises(ValueError, match="hole_measurements"):
        make_env(ENV_ID, obs_mode="measurements", hole_measurements=bad)


def test_a_non_finite_or_malformed_hole_pixel(make_env):
    """NaN or inf is no detection (as for the ball); a pixel of the wrong shape raises."""
    env = make_env(ENV_ID, obs_mode="measurements", hole_measurements=True, **LAB)
    observer = EndpointObserver(env.unwrapped)
    obs, info = env.reset(seed=1)
    observer.reset()
    obs, _, _, _, info = env.step(np.zeros(3, np.float32))
    frames = [dict(f, hole_uv_px=np.array([np.nan, 3.0])) for f in info["frames"]]
    estimate = observer.observe(obs, {**info, "frames": frames}, info["applied_action"])
    assert np.all(np.isfinite(estimate.mean))
    obs, _, _, _, info = env.step(np.zeros(3, np.float32))
    frames = [dict(f, hole_uv_px=np.zeros(3)) for f in info["frames"]]
    with pytest.raises(ValueError, match="hole_uv_px"):
        observer.observe(obs, {**info, "frames": frames}, info["applied_action"])
