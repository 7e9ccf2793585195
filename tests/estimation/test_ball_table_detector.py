"""The BallTable detector against the simulator's ground truth.

Frames come from ``observer_gym/BallTable-v0`` under smooth random tilts within +-0.08 rad
(a sinusoid per axis; random per-step jumps of that size make the ball hop off the table
by up to 3.4 mm, which no detector assuming p1_z = r can follow). Every bound below is a
module constant with the value it was set from (measured on these very frames, bound at
about 1.5x, rounded).
"""

from __future__ import annotations

import math

import cv2
import gymnasium as gym
import numpy as np
import pytest

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.envs.ball_table import geometry as geo
from observer_gym.envs.ball_table.layout import BALL_PX, CORNERS_PX, DETECTED
from observer_gym.envs.camera import project_points, sphere_image
from observer_gym.estimation.ball_table.features import (
    BORDER_OUTLINE,
    RED_TOP,
    features_from_measurement,
)
from observer_gym.estimation.ball_table.geometry_stage import BallTableDetector
from observer_gym.estimation.ball_table.image_stage import extract_features
from observer_gym.estimation.ball_table.tracker import TableTracker
from observer_gym.estimation.camera_geometry import pixel_ray, ray_plane_intersection

# Default detector (IPPE_SQUARE + joint 8-corner pose with the borders' outline), 155
# rendered frames, fixed camera and head motion together:
BALL_POS_RMSE_BOUND_M = 0.00045  # measured 0.30 mm
TILT_RMSE_BOUND_RAD = 0.004  # measured 2.8 mrad
# The red top's square alone (use_outline=False), the spec's pipeline:
SQUARE_TILT_RMSE_BOUND_RAD = {"ippe_square": 0.018, "ap3p": 0.026}  # measured 12.4, 17.3 mrad
SQUARE_BALL_POS_RMSE_BOUND_M = 0.0017  # measured 0.99 (ippe_square), 1.14 mm (ap3p)
# Ball radius unknown (the report's choice): r and d from p1_z = r, d = r / sin(alpha).
RADIUS_ERROR_BOUND_M = 0.001  # measured -0.39 ... +0.59 mm
UNKNOWN_RADIUS_POS_RMSE_BOUND_M = 0.00045  # measured 0.31 mm
# Perfect features (obs_mode="measurements"): PnP round-off and float32 pixels only.
PERFECT_POS_ERROR_BOUND_M = 0.0005  # the brief's bound; measured max 0.13 mm
PERFECT_TILT_ERROR_BOUND_RAD = 0.001  # the brief's bound; measured max 0.0004 mrad
# A pose the detector vouches for is never "wrong" (that is 0.1 rad off): on the hard
# frames (head motion of 15 deg; the occluder) the worst errors measured were 6.8 and
# 9.6 mrad of tilt (the red top alone, its outline cut off) and 0.54 and 0.98 mm.
WORST_TILT_ERROR_BOUND_RAD = 0.02
WORST_BALL_POS_ERROR_BOUND_M = 0.002
# Fallback on the outline alone (a red corner painted black, 1/3 along both its sides):
FALLBACK_TILT_RMSE_BOUND_RAD = 0.012  # measured 8.1 mrad

MAX_TILT_ACTION_RAD = 0.08


def _episode(seed: int, steps: int, **options):
    """[(obs, info), ...] of one episode under smooth random tilts."""
    env = gym.make("observer_gym/BallTable-v0", **options)
    try:
        obs, info = env.reset(seed=seed)
        frames = [(obs, info)]
        rng = np.random.default_rng(seed)
        amplitude = rng.uniform(0.5, 1.0, 2) * MAX_TILT_ACTION_RAD * rng.choice([-1, 1], 2)
        frequency_hz = rng.uniform(0.5, 1.5, 2)
        for step in range(steps):
            time_s = (step + 1) / 50.0
            action = amplitude * np.sin(2.0 * np.pi * frequency_hz * time_s)
            obs, _, terminated, _, info = env.step(action.astype(np.float32))
            frames.append((obs, info))
            if terminated:
                break
        return frames
    finally:
        env.close()


def _paired(seed: int, steps: int, **options):
    """[(rgb, info, measurement), ...]: the same episode rendered and as measurements
    (rendering does not touch the physics)."""
    rgb = _episode(seed, steps, obs_mode="rgb", **options)
    measured = _episode(seed, steps, obs_mode="measurements", **options)
    assert len(rgb) == len(measured)
    return [(obs, info, m) for (obs, info), (m, _) in zip(rgb, measured, strict=True)]


@pytest.fixture(scope="module")
def rendered():
    """[(features, info), ...] over fixed-camera and head-motion episodes."""
    frames = []
    for seed, motion in ((0, "fixed"), (1, "fixed"), (2, "fixed"), (3, "head"), (4, "head")):
        for obs, info in _episode(seed, 30, obs_mode="rgb", camera_motion=motion):
            camera = info["camera"]
            frames.append((extract_features(obs, camera["K"], camera["T_world_cam"]), info))
    return frames


def _errors(detector: BallTableDetector, frames):
    """(ball position errors (N, 2) m, tilt errors (N, 2) rad, radii (N,)) over the frames,
    asserting that the detector found table and ball in every one of them."""
    pos, tilt, radius = [], [], []
    for features, info in frames:
        camera = info["camera"]
        detection = detector.detect(features, camera["K"], camera["T_world_cam"])
        assert detection.table_found and detection.ball_found, detection.failure
        pos.append(detection.ball_pos_table_m - info["state"][0:2])
        tilt.append(detection.tilt_rad - info["state"][4:6])
        radius.append(detection.ball_radius_m)
    return np.array(pos), np.array(tilt), np.array(radius)


def _rmse(errors: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(errors**2, axis=1))))


def test_default_detector_on_rendered_frames(rendered):
    pos, tilt, _ = _errors(BallTableDetector(), rendered)
    assert _rmse(pos) < BALL_POS_RMSE_BOUND_M
    assert _rmse(tilt) < TILT_RMSE_BOUND_RAD
    # The borders' outline was found beside the red top in every one of these frames.
    assert all(f.corner_model == RED_TOP and f.outline_corners_px is not None for f, _ in rendered)


def test_corners_are_named_in_table_corner_order(rendered):
    """The detected corners match the projections of TABLE_CORNERS_TABLE, index by index."""
    worst_px = 0.0
    for features, info in rendered:
        camera = info["camera"]
        T = info["T_world_table"]
        corners_world = geo.TABLE_CORNERS_TABLE @ T[:3, :3].T + T[:3, 3]
        expected, _ = project_points(camera["K"], camera["T_world_cam"], corners_world)
        worst_px = max(worst_px, float(np.max(np.abs(features.corners_px - expected))))
    assert worst_px < 1.0


def test_pnp_methods_and_the_default(rendered):
    """On the red top's square alone, IPPE_SQUARE beats the report's AP3P (so it is the
    default); the joint 8-corner pose does not depend on the method."""
    tilt_rmse = {}
    for method in ("ippe_square", "ap3p"):
        pos, tilt, _ = _errors(BallTableDetector(method, use_outline=False), rendered)
        tilt_rmse[method] = _rmse(tilt)
        assert tilt_rmse[method] < SQUARE_TILT_RMSE_BOUND_RAD[method]
        assert _rmse(pos) < SQUARE_BALL_POS_RMSE_BOUND_M
    assert BallTableDetector().pnp_method == min(tilt_rmse, key=tilt_rmse.get)
    _, tilt_a, _ = _errors(BallTableDetector("ippe_square"), rendered)
    _, tilt_b, _ = _errors(BallTableDetector("ap3p"), rendered)
    np.testing.assert_allclose(tilt_a, tilt_b, atol=1e-9)
    assert _rmse(tilt_a) < 0.5 * min(tilt_rmse.values())  # the outline's worth


def test_unknown_ball_radius(rendered):
    pos, _, radius = _errors(BallTableDetector(ball_radius="unknown"), rendered)
    assert np.max(np.abs(radius - geo.BALL_RADIUS_M)) < RADIUS_ERROR_BOUND_M
    assert _rmse(pos) < UNKNOWN_RADIUS_POS_RMSE_BOUND_M


@pytest.mark.parametrize("camera_motion", ["fixed", "head"])
def test_measurements_mode_features(camera_motion):
    """Perfect features: only PnP's round-off (and float32 pixels) is left."""
    detector = BallTableDetector()
    frames = _episode(5, 60, obs_mode="measurements", camera_motion=camera_motion)
    for obs, info in frames:
        features = features_from_measurement(obs)
        assert features.source == "measurement" and features.outline_corners_px is None
        detection = detector.detect(features, info["camera"]["K"], info["camera"]["T_world_cam"])
        assert detection.table_found and detection.ball_found
        pos_error = np.linalg.norm(detection.ball_pos_table_m - info["state"][0:2])
        assert pos_error < PERFECT_POS_ERROR_BOUND_M
        assert (
            np.max(np.abs(detection.tilt_rad - info["state"][4:6])) < PERFECT_TILT_ERROR_BOUND_RAD
        )


def test_features_from_measurement_respects_the_detected_flags():
    obs = {
        CORNERS_PX: np.zeros(8, np.float32),
        BALL_PX: np.array([160.0, 120.0, 10.0], np.float32),
        DETECTED: np.array([0, 1], np.int8),
    }
    features = features_from_measurement(obs)
    assert features.corners_px is None and features.ball_px is not None
    detection = BallTableDetector().detect(features, np.eye(3), np.eye(4))
    assert not detection.table_found and not detection.ball_found  # no pose, no position


def _check_vouched(detection, info) -> None:
    """A pose or position the detector vouches for is right."""
    if detection.table_found:
        tilt_error = np.max(np.abs(detection.tilt_rad - info["state"][4:6]))
        assert tilt_error < WORST_TILT_ERROR_BOUND_RAD
    if detection.ball_found:
        pos_error = np.linalg.norm(detection.ball_pos_table_m - info["state"][0:2])
        assert pos_error < WORST_BALL_POS_ERROR_BOUND_M


def _detect_frame(detector: BallTableDetector, obs, info):
    """Both stages on one rendered frame, with its calibration from info."""
    camera = info["camera"]
    features = extract_features(obs, camera["K"], camera["T_world_cam"])
    return detector.detect(features, camera["K"], camera["T_world_cam"])


def test_table_out_of_view_is_flagged():
    """Narrow field of view (the corners fall outside the image), and a head moving by
    15 deg: whenever the perfect detector says the table is not all in view, the detector
    says not found; whatever it vouches for is right."""
    detector = BallTableDetector()
    for obs, info in _episode(0, 5, obs_mode="rgb", hfov_deg=40.0):
        camera = info["camera"]
        features = extract_features(obs, camera["K"], camera["T_world_cam"])
        assert features.corners_px is None and "clipped" in features.table_failure
        assert not detector.detect(features, camera["K"], camera["T_world_cam"]).table_found
    out_of_view = 0
    for obs, info, measured in _paired(0, 100, camera_motion="head", head_motion_deg=15.0):
        detection = _detect_frame(detector, obs, info)
        if not measured[DETECTED][0]:
            out_of_view += 1
            assert not detection.table_found
        _check_vouched(detection, info)
    assert out_of_view >= 5  # the case really happened


def test_occluder_hides_the_ball():
    """Frames whose ball the occluder hides give ball_found False; nothing vouched for is
    wrong."""
    detector = BallTableDetector()
    hidden = 0
    for obs, info, measured in _paired(2, 100, occluder_rate_hz=2.0, occluder_pass_s=1.0):
        detection = _detect_frame(detector, obs, info)
        if not measured[DETECTED][1]:
            hidden += 1
            assert not detection.ball_found
        _check_vouched(detection, info)
    assert hidden >= 3


def _paint_corner_black(obs, info, corner: int) -> np.ndarray:
    """The frame with the red top's ``corner`` painted border-black over a third of both
    its sides: the red top then has no 4 valid corners; the outline is intact."""
    camera = info["camera"]
    T = info["T_world_table"]
    corners_world = geo.TABLE_CORNERS_TABLE @ T[:3, :3].T + T[:3, 3]
    uv, _ = project_points(camera["K"], camera["T_world_cam"], corners_world)
    c, before, after = uv[corner], uv[corner - 1], uv[(corner + 1) % 4]
    triangle = np.array([c, c + (before - c) / 3.0, c + (after - c) / 3.0])
    painted = obs.copy()
    cv2.fillConvexPoly(painted, np.rint(triangle).astype(np.int32), (11, 11, 11))
    return painted


def test_black_border_fallback():
    detector = BallTableDetector()
    tilt_errors = []
    for obs, info in _episode(6, 20, obs_mode="rgb")[::2]:
        camera = info["camera"]
        ball = np.asarray(info["state"][0:2])
        # The corner farthest from the ball, so the paint does not touch it.
        corner = int(np.argmax(np.linalg.norm(geo.TABLE_CORNERS_TABLE[:, :2] - ball, axis=1)))
        painted = _paint_corner_black(obs, info, corner)
        features = extract_features(painted, camera["K"], camera["T_world_cam"])
        assert features.corner_model == BORDER_OUTLINE, features.table_failure
        assert features.table_failure == "red_top: corners"
        detection = detector.detect(features, camera["K"], camera["T_world_cam"])
        assert detection.table_found and detection.ball_found
        tilt_errors.append(detection.tilt_rad - info["state"][4:6])
    assert _rmse(np.array(tilt_errors)) < FALLBACK_TILT_RMSE_BOUND_RAD


@pytest.mark.parametrize("seed", range(3))
def test_ball_geometry_on_an_exact_sphere_image(seed):
    """Spec steps 2-4 on the exact image of a ball resting on the table (envs.camera's
    sphere_image) give back its position, and match camera_geometry's pixel_ray and
    ray_plane_intersection; with r unknown they solve p1_z = r, d = r / sin(alpha)."""
    rng = np.random.default_rng(seed)
    K = np.array([[160.0, 0.0, 160.0], [0.0, 160.0, 120.0], [0.0, 0.0, 1.0]])
    R_cam_table, _ = cv2.Rodrigues(np.array([math.pi, 0.0, 0.0]) + rng.normal(0, 0.2, 3))
    t_cam_table = np.array([0.0, 0.0, 0.45]) + rng.normal(0, 0.03, 3)
    T_table_cam = np.eye(4)  # the camera's pose in the table frame
    T_table_cam[:3, :3], T_table_cam[:3, 3] = R_cam_table.T, -R_cam_table.T @ t_cam_table
    r = geo.BALL_RADIUS_M
    ball_table = np.array([*rng.uniform(-0.1, 0.1, 2), r])
    centre_px, rho, _ = sphere_image(K, T_table_cam, ball_table, r)
    ball_px = np.array([*centre_px, rho])

    position, radius, distance = BallTableDetector().ball_position(
        ball_px, K, R_cam_table, t_cam_table
    )
    np.testing.assert_allclose(position, ball_table[:2], atol=1e-9)
    np.testing.assert_allclose(distance, np.linalg.norm(ball_table - T_table_cam[:3, 3]))

    e = (centre_px - K[:2, 2]) / np.linalg.norm(centre_px - K[:2, 2])
    vertices = np.stack([centre_px + rho * e, centre_px - rho * e])
    eye, (v_a, v_b) = pixel_ray(K, T_table_cam, vertices)
    v1 = (v_a + v_b) / np.linalg.norm(v_a + v_b)
    expected = ray_plane_intersection(eye, v1, [0.0, 0.0, r], [0.0, 0.0, 1.0])
    np.testing.assert_allclose(position, expected[:2], atol=1e-12)

    unknown = BallTableDetector(ball_radius="unknown")
    position, radius, distance = unknown.ball_position(ball_px, K, R_cam_table, t_cam_table)
    np.testing.assert_allclose([position[0], position[1], radius], ball_table, atol=1e-9)
    sin_alpha = math.sin(0.5 * math.acos(v_a @ v_b))
    np.testing.assert_allclose(distance, radius / sin_alpha, rtol=1e-12)


def _assert_same_features(tracked, searched) -> None:
    """The tracked region's features are the full search's (the same pixels in both)."""
    assert (tracked.corner_model, tracked.table_failure, tracked.ball_failure) == (
        searched.corner_model,
        searched.table_failure,
        searched.ball_failure,
    )
    for name in ("corners_px", "outline_corners_px", "ball_px"):
        a, b = getattr(tracked, name), getattr(searched, name)
        assert (a is None) == (b is None), name
        if a is not None:
            np.testing.assert_allclose(a, b, rtol=0.0, atol=1e-9, err_msg=name)


def _track(tracker: TableTracker, obs, info):
    """(tracked features, full-search features, whether the tracker searched) of a frame."""
    camera = info["camera"]
    K, T_world_cam = camera["K"], camera["T_world_cam"]
    searched_before = tracker.searched_frames
    tracked = tracker.extract_features(obs, K, T_world_cam)
    searched = tracker.searched_frames > searched_before
    return tracked, extract_features(obs, K, T_world_cam), searched


@pytest.mark.parametrize(
    "options",
    [
        # the table leaves the view (2.6 s idle, slow; test_table_out_of_view_is_flagged stays)
        pytest.param({"camera_motion": "head", "head_motion_deg": 15.0}, marks=pytest.mark.slow),
        # (1.8 s idle, slow; test_occluder_hides_the_ball stays)
        pytest.param({"occluder_rate_hz": 2.0, "occluder_pass_s": 1.0}, marks=pytest.mark.slow),
        {"camera_motion": "fixed"},
    ],
    ids=["head_15deg", "occluder", "fixed"],
)
def test_tracked_region_gives_the_full_search_features(options):
    """Frame by frame, the tracker's features are the full search's; a frame whose table
    is flagged comes from the full search, and so does the frame after it."""
    tracker = TableTracker()
    flagged_before, flagged = True, 0
    for obs, info in _episode(seed=0, steps=100, obs_mode="rgb", **options):
        tracked, searched_features, searched = _track(tracker, obs, info)
        _assert_same_features(tracked, searched_features)
        if tracked.corners_px is None:
            flagged += 1
            assert searched and tracker.boxes is None
        if flagged_before:
            assert searched
        flagged_before = tracked.corners_px is None
    if "head_motion_deg" in options:
        assert flagged >= 5  # the table really left the view
        assert tracker.tracked_frames >= 30  # and was tracked in between
    else:
        assert tracker.searched_frames <= 1 + 2 * flagged  # the tracked path is the usual one


def _shifted(obs: np.ndarray, du: int, dv: int) -> np.ndarray:
    """The frame moved by (du, dv) pixels, the uncovered part filled with the background."""
    moved = np.full_like(obs, 255)
    h, w = obs.shape[:2]
    moved[max(dv, 0) : h + min(dv, 0), max(du, 0) : w + min(du, 0)] = obs[
        max(-dv, 0) : h - max(dv, 0), max(-du, 0) : w - max(du, 0)
    ]
    return moved


def test_tracked_region_falls_back_when_the_table_jumps_or_leaves():
    """The table jumping out of the tracked region, out of the image's edge, or out of view
    altogether: each time the tracker searches the whole frame, gives the full search's
    features (the jump found, the others flagged) and tracks again once the table is back."""
    frames = _episode(seed=1, steps=4, obs_mode="rgb")
    tracker = TableTracker()
    obs, info = frames[0]
    tracked, _, searched = _track(tracker, obs, info)
    assert searched and tracked.corners_px is not None  # the first frame is searched
    tracked, _, searched = _track(tracker, *frames[1])
    assert not searched and tracked.corners_px is not None

    jumped = _shifted(frames[2][0], 12, -7)  # further than the tracked region allows
    tracked, searched_features, searched = _track(tracker, jumped, frames[2][1])
    _assert_same_features(tracked, searched_features)
    assert searched and tracked.corner_model == RED_TOP  # found, by the full search
    before = extract_features(frames[2][0], **_calibration(frames[2][1]))
    np.testing.assert_allclose(tracked.corners_px, before.corners_px + np.array([12, -7]))

    for away in (_shifted(frames[3][0], 120, 0), np.full_like(frames[3][0], 255)):
        tracked, searched_features, searched = _track(tracker, away, frames[3][1])
        _assert_same_features(tracked, searched_features)
        assert searched and tracked.corners_px is None  # flagged (clipped; not in view)
        assert tracker.boxes is None
    tracked, _, searched = _track(tracker, *frames[4])
    assert searched and tracked.corners_px is not None  # back: searched, then tracked
    tracked, _, searched = _track(tracker, *frames[4])
    assert not searched and tracked.corners_px is not None


def _calibration(info) -> dict:
    return {"K": info["camera"]["K"], "T_world_cam": info["camera"]["T_world_cam"]}


def test_bad_options_raise():
    with pytest.raises(ValueError, match="pnp_method"):
        BallTableDetector(pnp_method="epnp")
    with pytest.raises(ValueError, match="ball_radius"):
        BallTableDetector(ball_radius="maybe")
