"""The learned observers from rendered frames (BallTable, TargetFollower): the learned
detector's error, NEES and detected flags on frames of seeds its training never drew, the
observers' layout and covariance through it, the closed loop on it (error and NEES
against the bounds measured), refusal of a changed detector file, and the training
command's errors."""

from __future__ import annotations

import shutil
from types import ModuleType

import gymnasium as gym
import numpy as np
import pytest
from closed_loop import closed_loop as shared_closed_loop

from observer_gym.estimation import VisionObserver
from observer_gym.estimation.ball_table import learned_detector as ball_table
from observer_gym.estimation.learned.frame_detector import LearnedDetector
from observer_gym.estimation.learned.frame_training import detector_report
from observer_gym.estimation.target_follower import learned_detector as target_follower
from observer_gym.train.experiments.learned_observers import ball_table as ball_table_data
from observer_gym.train.experiments.learned_observers import (
    target_follower as target_follower_data,
)
from observer_gym.train.experiments.learned_observers.train_detector import main as train_detector

NEW_SEED = 10**6  # the training draws its episode seeds from seed 0's generator

# system -> (env id, its learned detector module, controller, steps of a closed-loop episode)
SYSTEMS: dict[str, tuple[str, ModuleType, str, int]] = {
    "BallTable-v0": ("observer_gym/BallTable-v0", ball_table, "lqr", 250),
    "TargetFollower-v0": ("observer_gym/TargetFollower-v0", target_follower, "vtc", 150),
}
# system -> its training data's collection (train/experiments/learned_observers/)
COLLECTIONS: dict[str, ModuleType] = {
    "BallTable-v0": ball_table_data,
    "TargetFollower-v0": target_follower_data,
}

# The detector on 3 lockstep episodes of 60 steps of a new seed (frames 0, 2, ...), as
# measured on 2026-11-26 (value RMSE in px, NEES/dof): the bounds are 1.5x the RMSE
# measured and half to twice the NEES measured.
#   BallTable: corners 0.04-0.07 px, ball centre 1.01 and 1.13 px, semi-major axis 0.02
#   px, NEES/dof 1.23; TargetFollower: x_i, y_i, d_x 0.60, 0.50, 0.51 px, NEES/dof 1.33.
DETECTOR_BOUNDS = {
    "BallTable-v0": ([0.11] * 8 + [1.5, 1.7, 0.036], (0.62, 2.46)),
    "TargetFollower-v0": ([0.9, 0.75, 0.77], (0.67, 2.66)),
}


@pytest.fixture(  # BallTable's frames (its detector 3.9 s, its closed loop 5.4 s at load ~2): slow
    scope="module",
    params=[pytest.param(s, marks=pytest.mark.slow) if s == "BallTable-v0" else s for s in SYSTEMS],
)
def system(request):
    return request.param


@pytest.fixture(scope="module")
def new_frames(system):
    return COLLECTIONS[system].collect_frames(3, NEW_SEED, steps=60)


def test_the_detector_reads_frames_of_a_new_seed_within_its_measured_error(system, new_frames):
    _, module, _, _ = SYSTEMS[system]
    detector = LearnedDetector(module.WEIGHTS)
    report = detector_report(detector.net, new_frames)
    rmse_bounds, (nees_low, nees_high) = DETECTOR_BOUNDS[system]
    assert np.all(np.array(report["rmse_px"]) <= rmse_bounds), report
    assert nees_low <= report["nees_per_dof"] <= nees_high, report
    assert min(report["detected_right"]) >= 0.98, report


def test_the_detector_file_ships_with_its_report(system):
    _, module, _, _ = SYSTEMS[system]
    detector = LearnedDetector(module.WEIGHTS)
    report = detector.report
    assert report["command"].endswith(f"--env {system}")
    assert tuple(report["camera_px"]) == detector.camera_px == module.CAMERA_PX
    assert report["frames"] == report["train_frames"] + report["held_out"]["frames"]


def test_a_changed_detector_file_is_refused(system, tmp_path):
    _, module, _, _ = SYSTEMS[system]
    weights = tmp_path / module.WEIGHTS.name
    shutil.copy(module.WEIGHTS, weights)
    shutil.copy(module.WEIGHTS.with_suffix(".json"), weights.with_suffix(".json"))
    LearnedDetector(weights)  # the untouched copy loads
    data = bytearray(weights.read_bytes())
    data[-100] ^= 0xFF
    weights.write_bytes(bytes(data))
    with pytest.raises(ValueError, match="a changed file is refused"):
        LearnedDetector(weights)


@pytest.mark.parametrize("observer", ["learned", "learned-kf"])
def test_from_frames_the_estimate_has_the_state_layout_and_a_symmetric_covariance(system, observer):
    env_id, _, _, _ = SYSTEMS[system]
    env = VisionObserver(gym.make(env_id, obs_mode="rgb"), observer=observer)
    try:
        estimate, info = env.reset(seed=0)
        n = env.unwrapped.state_space.shape[0]
        for _ in range(5):
            action = np.zeros(env.action_space.shape, dtype=np.float32)
            estimate, _, _, _, info = env.step(action)
            P = info["estimate"]["covariance"]
            assert estimate.shape == (n,) and P.shape == (n, n)
            assert np.allclose(P, P.T) and np.all(np.diag(P) >= 0.0)
    finally:
        env.close()


# The closed loop on the estimate from frames, 1 episode of a new seed: (the entries
# compared, the bound on their RMSE: 1.5x the measured, the band of the median NEES/dof
# over them: half to twice the measured). Measured on 2026-11-26, learned-kf on
# 2026-11-28 fusing one network output in two frames (learned_kf.py; fusing every one it
# was 3.14 mm, NEES/dof 2.96, and 1.37 px, 0.94):
#   BallTable (ball position, m): learned 5.67 mm, NEES/dof 1.89; learned-kf 4.38 mm, 1.72
#   TargetFollower (X_i, px): learned 1.66 px, NEES/dof 0.38; learned-kf 1.64 px, 0.72
# BallTable's re-measured on 2026-11-29 with the "rgb" variance scale (fitted across the
# frames part's image noise and latency, estimation/ball_table/learned.json): learned
# 5.67 mm, 0.28; learned-kf 4.14 mm, 0.35. The scale holds the study's per-episode mean
# NEES/dof near 1 (tests/estimation/test_learned_frames_consistency.py); the frames'
# errors are heavy-tailed, so the per-step median here falls below it. With the scale by
# the newest frame's age (the same file, 2026-11-29): learned 0.30; learned-kf 4.15 mm, 0.36.
CLOSED_LOOP_BOUNDS = {
    ("BallTable-v0", "learned"): (slice(0, 2), 0.0085, (0.14, 0.56)),
    ("BallTable-v0", "learned-kf"): (slice(0, 2), 0.0066, (0.17, 0.70)),
    ("TargetFollower-v0", "learned"): (slice(0, 3), 2.5, (0.19, 0.76)),
    ("TargetFollower-v0", "learned-kf"): (slice(0, 3), 2.46, (0.36, 1.44)),
}


def closed_loop(system: str, observer: str, seed: int = NEW_SEED) -> tuple[float, float]:
    """(RMSE over the compared entries, median NEES/dof over them) of the system's
    controller on ``observer``'s estimate from frames, one episode of ``seed``."""
    env_id, _, controller_name, steps = SYSTEMS[system]
    entries = CLOSED_LOOP_BOUNDS[system, observer][0]
    errors, nees = [], []
    loop = shared_closed_loop(
        lambda: gym.make(env_id, obs_mode="rgb"), controller_name, [seed], steps, observer=observer
    )
    for step in loop:
        e = (step.info["estimate"]["mean"] - step.info["state"])[entries]
        P = step.info["estimate"]["covariance"][entries, entries]
        errors.append(e)
        nees.append(e.dot(np.linalg.solve(P, e)) / len(e))
        if step.terminated or step.truncated:
            break
    loop.close()
    return float(np.sqrt(np.mean(np.sum(np.square(errors), axis=1)))), float(np.median(nees))


@pytest.mark.parametrize(  # the network alone on frames: slow (learned-kf runs it too)
    "observer", [pytest.param("learned", marks=pytest.mark.slow), "learned-kf"]
)
def test_the_closed_loop_on_frames_keeps_the_measured_error_and_nees(system, observer):
    _, bound, (low, high) = CLOSED_LOOP_BOUNDS[system, observer]
    error, nees = closed_loop(system, observer)
    assert error <= bound, (error, nees)
    assert low <= nees <= high, (error, nees)


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--env", "CartPole-v1"], "no learned detector for 'CartPole-v1'"),
        (["--env", "BallTable-v0", "--epochs", "0"], "--epochs >= 1"),
        (["--env", "BallTable-v0", "--out", "x.pth"], "--out must end in .pt"),
        (["--env", "BallCatcher-v1", "--episodes", "3"], "--episodes must be >= 5"),
    ],
)
def test_the_training_command_says_a_mistake_in_one_line(argv, message, capsys):
    assert train_detector(argv) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


def test_a_command_line_mistake_is_one_line_and_exit_code_2(capsys):
    with pytest.raises(SystemExit) as exc:
        train_detector(["--env", "BallTable-v0", "--seed", "-1"])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "--seed" in err and err.count("\n") == 1


def test_a_cache_of_other_frames_is_refused_not_overwritten(tmp_path, capsys):
    cache = tmp_path / "frames.npz"
    np.savez(cache, key=np.array(["TargetFollower-v0", "100", "0"]))
    before = cache.read_bytes()
    out = tmp_path / "detector.pt"
    argv = ["--env", "BallTable-v0", "--cache", str(cache), "--out", str(out)]
    assert train_detector(argv) == 2
    err = capsys.readouterr().err
    assert "holds the frames of (env, episodes, seed) = ['TargetFollower-v0'" in err, err
    assert err.count("\n") == 1 and cache.read_bytes() == before and not out.exists()


@pytest.mark.slow  # two frame-detector trainings (1.6-2.4 s idle); the learned observers'
# measurement trainings are checked for it in the default run (test_learned_ball_table.py)
def test_training_is_reproducible_from_its_seed():
    """The same data and seed give the same tensors (a tiny run: 5 episodes of 4 steps,
    one epoch)."""
    import torch

    from observer_gym.estimation.learned.frame_training import fit_detector

    data = ball_table_data.collect_frames(5, 3, steps=4)
    again = ball_table_data.collect_frames(5, 3, steps=4)
    assert all(np.array_equal(a, b) for a, b in zip(data, again, strict=True))
    first, _ = fit_detector(data, ball_table.VALUE_PARTS, seed=1, epochs=1)
    second, _ = fit_detector(data, ball_table.VALUE_PARTS, seed=1, epochs=1)
    for (name, a), b in zip(first.state_dict().items(), second.state_dict().values(), strict=True):
        assert torch.equal(a, b), name
