"""BallCatcher's learned observers from rendered frames (estimation/ball_catcher/
learned_detector.py, estimation/learned/heatmap_detector.py): the learned detector's
pixel error, NEES and detected flags on whole frames of a seed its training never drew,
the shipped file and its report, refusal of a changed file and of another image size,
the observers' layout and covariance through it, the closed loop on it against the bounds
measured, reproducible training, the heat map's decoding and bad input.

Measured on 2026-11-26 with the shipped weights; each bound is the measured value x 1.5
(errors) or half to twice it (NEES/dof), the measured value beside it.
"""

from __future__ import annotations

import functools
import shutil
from typing import NamedTuple

import gymnasium as gym
import numpy as np
import pytest
import torch
from ball_catcher_throws import intercept_throws

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.envs.ball_catcher.layout import STATE_DIM
from observer_gym.estimation import VisionObserver
from observer_gym.estimation.ball_catcher import OBSERVERS
from observer_gym.estimation.ball_catcher import learned_detector as ball_catcher
from observer_gym.estimation.learned.frame_training import FrameDataset
from observer_gym.estimation.learned.heatmap_detector import (
    LearnedPointDetector,
    PointHeatmapNet,
    fit_point_detector,
    point_report,
)
from observer_gym.train.experiments.learned_observers import ball_catcher as ball_catcher_data
from observer_gym.train.experiments.learned_observers.frame_data import collect_lockstep

ENV = "observer_gym/BallCatcher-v1"
NEW_SEED = 10**6  # the training draws its episode seeds from seed 0's generator
THROWS = 3


@functools.cache
def _new_frames():
    """Whole frames (3, 240, 320) of 3 lockstep throws of a new seed, every frame delivered."""
    return ball_catcher_data.collect_frames(3, NEW_SEED, crop_px=None)


@pytest.mark.slow  # renders a new seed's frames: 3.6 s (load ~2)
def test_the_detector_reads_whole_frames_of_a_new_seed_within_its_measured_error():
    """3 throws of a new seed, 141 whole frames (133 with the ball's centre in the image),
    measured: RMSE 0.120 and 0.110 px (u, v) over the frames both it and the label
    detect, none over 3 px, NEES/dof 0.66, flags right on 97.9 % (2 missed: the ball
    entering the box's hole, hidden, which the perfect detector reports; 1 false: the
    ball half out of the image's left edge, its centre just outside)."""
    detector = LearnedPointDetector(ball_catcher.WEIGHTS)
    report = point_report(detector.net, _new_frames())
    assert report["frames"] == 141, report
    assert np.all(np.array(report["rmse_px"]) <= [0.18, 0.165]), report  # 0.120, 0.110
    assert report["over_3px"] == 0.0, report
    assert 0.33 <= report["nees_per_dof"] <= 1.32, report  # 0.66
    assert report["detected_right"][0] >= 1 - 1.5 * 0.0213, report  # 0.9787


def test_the_detector_file_ships_small_with_its_report():
    detector = LearnedPointDetector(ball_catcher.WEIGHTS)
    report = detector.report
    assert report["command"].endswith("--env BallCatcher-v1")
    assert tuple(report["camera_px"]) == detector.camera_px == ball_catcher.CAMERA_PX
    assert report["frames"] == report["train_frames"] + report["held_out"]["frames"]
    assert ball_catcher.WEIGHTS.stat().st_size == ball_catcher.WEIGHT_BYTES


def test_a_changed_detector_file_is_refused(tmp_path):
    weights = tmp_path / ball_catcher.WEIGHTS.name
    shutil.copy(ball_catcher.WEIGHTS, weights)
    shutil.copy(ball_catcher.WEIGHTS.with_suffix(".json"), weights.with_suffix(".json"))
    LearnedPointDetector(weights)  # the untouched copy loads
    data = bytearray(weights.read_bytes())
    data[-100] ^= 0xFF
    weights.write_bytes(bytes(data))
    env = gym.make(ENV, obs_mode="rgb")
    try:
        for name in ("learned", "learned-kf"):
            with pytest.raises(ValueError, match="a changed file is refused"):
                OBSERVERS[name](env.unwrapped, detector_weights=weights)
    finally:
        env.close()


def test_another_image_size_is_refused_in_one_line():
    env = gym.make(ENV, obs_mode="rgb", image_width_px=160, image_height_px=120)
    try:
        with pytest.raises(ValueError, match="trained on 320 x 240 px camera images"):
            OBSERVERS["learned"](env.unwrapped)
    finally:
        env.close()


@pytest.mark.parametrize("observer", ["learned", "learned-kf"])
def test_from_frames_the_estimate_has_the_state_layout_and_a_symmetric_covariance(observer):
    env = VisionObserver(gym.make(ENV, obs_mode="rgb"), observer=observer)
    try:
        env.reset(seed=0)
        for _ in range(15):
            estimate, _, _, _, info = env.step(np.zeros(3, np.float32))
            P = info["estimate"]["covariance"]
            assert estimate.shape == (STATE_DIM,) and P.shape == (STATE_DIM, STATE_DIM)
            assert np.allclose(P, P.T) and np.all(np.diag(P) >= 0.0)
    finally:
        env.close()


class ClosedLoop(NamedTuple):
    rmse_m: np.ndarray  # (3,): the ball's position, x, y, z
    median_m: float  # the median of the position error's norm
    median_nees_per_dof: float  # over the ball's six entries


@functools.cache
def _closed_loop(observer: str, obs_mode: str = "rgb") -> ClosedLoop:
    """``intercept`` on ``observer``'s estimate, 3 throws of new seeds, the free flight
    from 0.1 s after the launch to the crossing of the box's plane."""
    throws = intercept_throws(
        lambda: gym.make(ENV, obs_mode=obs_mode), observer, range(NEW_SEED, NEW_SEED + THROWS)
    )
    errors, nees = throws.errors, throws.nees_per_dof
    position = np.array(errors)[:, :3]
    return ClosedLoop(
        np.sqrt(np.mean(np.square(position), axis=0)),
        float(np.median(np.linalg.norm(position, axis=1))),
        float(np.median(nees)),
    )


# observer -> (position RMSE bound (m, x y z), median error bound (m), NEES/dof band),
# measured on 2026-11-26 (beside them, the same throws from the perfect detector's
# measurements at the default 0.5 px, and kf from the same frames):
#   learned: RMSE 260.6, 26.0, 31.0 mm, median 7.97 mm, NEES/dof 0.35 (measurements: 10.7,
#     3.0, 4.8 mm, median 9.7 mm, 0.53). The RMSE is one step per throw: the last before
#     the box's plane, where the ball at the hole is hidden from camera 1 behind the box
#     after camera 0 lost it at the image's edge; the network, trained on the perfect
#     detector (no occlusion), never saw both cameras' newest frames without the ball
#     then and errs by up to 1.36 m there (docs/observers.md).
#   learned-kf (measured 2026-11-28, one network output fused in four steps,
#     learned_kf.py): RMSE 11.2, 1.5, 5.2 mm, median 11.4 mm, NEES/dof 1.59 (measurements:
#     13.6, 2.3, 4.5 mm, median 12.9 mm, 1.98); fusing every step's output it was 9.8,
#     1.4, 4.5 mm, median 10.3 mm, 4.15 (measurements 5.72). A frame without the ball is
#     no update.
#   kf from the same frames: 0.53, 0.57, 0.35 mm, median 0.60 mm, NEES/dof 0.44.
CLOSED_LOOP_BOUNDS = {
    "learned": ([0.391, 0.039, 0.0465], 0.012, (0.176, 0.70)),
    "learned-kf": ([0.0168, 0.00225, 0.0078], 0.0171, (0.80, 3.18)),
}


@pytest.mark.parametrize(  # the network alone on frames: slow (learned-kf runs it too)
    "observer", [pytest.param("learned", marks=pytest.mark.slow), "learned-kf"]
)
def test_the_closed_loop_on_frames_keeps_the_measured_error_and_nees(observer):
    rmse_bound, median_bound, (low, high) = CLOSED_LOOP_BOUNDS[observer]
    result = _closed_loop(observer)
    assert np.all(result.rmse_m <= rmse_bound), result
    assert result.median_m <= median_bound, result
    assert low <= result.median_nees_per_dof <= high, result


@pytest.mark.slow  # two frame-detector trainings (1.6-2.4 s idle); the learned observers'
# measurement trainings are checked for it in the default run (test_learned_ball_table.py)
def test_training_is_reproducible_from_its_seed():
    """The same data and seed give the same tensors (a tiny run: 5 throws of 6 steps, one
    epoch); the crops hold the ball where their labels say."""
    data = ball_catcher_data.collect_frames(5, 3, steps=6)
    again = ball_catcher_data.collect_frames(5, 3, steps=6)
    assert all(np.array_equal(a, b) for a, b in zip(data, again, strict=True))
    assert data.frames.shape[1:] == (3, ball_catcher.CROP_PX, ball_catcher.CROP_PX)
    seen = data.detected[:, 0] > 0.5
    assert 0 < seen.sum() < len(seen)
    first, report = fit_point_detector(data, seed=1, epochs=1)
    second, _ = fit_point_detector(data, seed=1, epochs=1)
    for (name, a), b in zip(first.state_dict().items(), second.state_dict().values(), strict=True):
        assert torch.equal(a, b), name
    assert report["train_episodes"] == 4 and report["held_out_episodes"] == 1


def test_decode_reads_the_most_likely_cell_its_offset_and_variance():
    """Cell (i, j) = (5, 7) has the largest logit: (u, v) = 4 (j, i) + 4 offset, the
    variances exp(log-variance), the probability the logit's sigmoid."""
    out = torch.full((1, 5, 12, 16), -5.0)
    out[0, :, 5, 7] = torch.tensor([2.0, 0.25, -0.5, np.log(0.04), np.log(0.09)])
    uv, variance, probability = PointHeatmapNet.decode(out)
    np.testing.assert_allclose(uv[0], [4 * 7 + 1.0, 4 * 5 - 2.0])
    np.testing.assert_allclose(variance[0], [0.04, 0.09], rtol=1e-6)
    np.testing.assert_allclose(probability[0], 1 / (1 + np.exp(-2.0)), rtol=1e-6)


def test_bad_input_is_refused_in_one_line():
    with pytest.raises(ValueError, match="channels = 1, must be an int >= 2"):
        PointHeatmapNet(1)
    frames = np.zeros((4, 3, 8, 8), np.uint8)
    data = FrameDataset(frames, np.zeros((4, 3)), np.zeros((4, 1)), np.arange(4))
    with pytest.raises(ValueError, match=r"values \(N, 2\) and detected \(N, 1\)"):
        fit_point_detector(data, seed=0, epochs=1)
    with pytest.raises(ValueError, match="needs samples_of, or labels_of and net_size_px"):
        collect_lockstep(
            ENV, 1, 0, steps=1, stride=1, ranges={}, controller="intercept", noise_range=(0, 0)
        )
