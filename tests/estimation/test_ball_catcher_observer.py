"""The BallCatcher observer: the detector against projected ground truth, the viewline
filter's estimate through VisionObserver (measurements and rgb), late frames, and the
estimate's consistency with its covariance."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.envs.camera import project_points
from observer_gym.envs.sim import GRAVITY_MPS2
from observer_gym.estimation import VisionObserver
from observer_gym.estimation.ball_catcher.detector import BallCatcherDetector
from observer_gym.estimation.ball_catcher.observer import BallCatcherObserver

ENV_ID = "observer_gym/BallCatcher-v0"


def parabola(throw: dict, t_s: float) -> np.ndarray:
    p = throw["launch_pos_world"] + throw["launch_vel_world"] * t_s
    p[2] -= 0.5 * GRAVITY_MPS2 * t_s**2
    return p


def flights(env, seeds, steps=60):
    """(info after reset, [info after each step]) per seed, the box held still."""
    for seed in seeds:
        _, first = env.reset(seed=seed)
        infos = []
        for _ in range(steps):
            *_, terminated, _, info = env.step(np.zeros(3, np.float32))
            infos.append(info)
            if terminated:
                break
        yield first, infos


def test_detector_finds_the_ball_centre_to_a_tenth_of_a_pixel():
    """Every frame of 6 flights with the ball wholly in view and in front of the box:
    the detector against the projection of the true centre at the capture time."""
    env = gym.make(ENV_ID, obs_mode="rgb")
    detector = BallCatcherDetector()
    errors, missed = [], 0
    try:
        for first, infos in flights(env.unwrapped, range(6)):
            throw = first["throw"]
            for info in infos:
                for frame in info["frames"]:
                    t = frame["capture_time_s"]
                    if t > throw["crossing_time_s"] - 0.03:  # near or in the box
                        continue
                    uv, _ = project_points(
                        frame["K"], frame["T_world_cam"], parabola(throw, t)[None]
                    )
                    if not (5 < uv[0, 0] < 315 and 5 < uv[0, 1] < 235):
                        continue
                    found = detector.detect(frame["image"])
                    if found is None:
                        missed += 1
                    else:
                        errors.append(found - uv[0])
    finally:
        env.close()
    errors = np.array(errors)
    assert len(errors) > 150 and missed <= 0.02 * len(errors)
    rmse_px = np.sqrt(np.mean(errors**2, axis=0))
    assert np.all(rmse_px < 0.15), rmse_px  # measured 0.09 px
    assert np.abs(errors).max() < 0.5


def test_detector_reports_nothing_for_an_empty_or_cut_ball():
    detector = BallCatcherDetector()
    image = np.full((240, 320, 3), 255, np.uint8)
    assert detector.detect(image) is None
    image[100:106, 0:4] = (20, 200, 20)  # a green blob cut by the left edge
    assert detector.detect(image) is None
    image[100:106, 50:56] = (20, 200, 20)
    np.testing.assert_allclose(detector.detect(image), (52.5, 102.5))


@pytest.mark.parametrize("obs_mode", ["measurements", "rgb"])
def test_estimate_converges_near_the_box(obs_mode):
    """Position error over the 0.1 s before the ball reaches the box's plane (up to 10 ms
    before: by then the ball touches the plate when it misses, and its flight is no
    longer ballistic): measurements (0.5 px noise) and rendered frames; the NEES of
    those samples stays in the range a consistent filter gives (mean 3 for chi2(3))."""
    env = VisionObserver(gym.make(ENV_ID, obs_mode=obs_mode))
    errors_m, nees = [], []
    try:
        for first, infos in flights(env, range(8 if obs_mode == "measurements" else 4)):
            crossing_s = first["throw"]["crossing_time_s"]
            for info in infos:
                if not crossing_s - 0.1 <= info["time_s"] < crossing_s - 0.01:
                    continue
                est = info["estimate"]
                error = est["mean"][:3] - info["state"][:3]
                errors_m.append(np.linalg.norm(error))
                nees.append(error @ np.linalg.solve(est["covariance"][:3, :3], error))
    finally:
        env.close()
    errors_m = np.array(errors_m)
    assert len(errors_m) >= 30
    bound_m = 0.006 if obs_mode == "measurements" else 0.003  # measured 2.5 / 0.6 mm median
    assert np.median(errors_m) < bound_m / 2 and np.percentile(errors_m, 90) < bound_m
    if obs_mode == "measurements":  # the noise is the filter's model: NEES ~ chi2(3)
        assert 1.0 < np.mean(nees) < 6.0, np.mean(nees)


def test_late_frames_are_used_not_dropped():
    """random_offsets: each camera has its own latency, so frames arrive out of capture
    order; the filter re-filters them and uses every detection."""
    env = VisionObserver(gym.make(ENV_ID, obs_mode="measurements", camera_preset="random_offsets"))
    try:
        late = used = detections = 0
        for _, infos in flights(env, range(6)):
            kf = env.pipeline.filter
            late += kf.late_count
            used += kf.accepted_count + kf.rejected_count
            detections += sum(f["uv_px"] is not None for i in infos for f in i["frames"])
    finally:
        env.close()
    assert late > 0
    assert used == detections


def test_observer_rejects_another_env():
    env = gym.make("observer_gym/BallTable-v0", obs_mode="measurements")
    try:
        with pytest.raises(ValueError, match="BallCatcherEnv"):
            BallCatcherObserver(env.unwrapped)
    finally:
        env.close()
