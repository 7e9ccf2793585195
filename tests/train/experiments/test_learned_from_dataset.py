"""The learned observers' training data read from recorded datasets (one format in the
house): BallTable's and TargetFollower's arrays from a recording equal those of their
collections before they recorded (frozen copies below), and the trainer runs end to end
from a dataset."""

from __future__ import annotations

import warnings
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

pytest.importorskip("minari")

from observer_gym.controllers import make_controller
from observer_gym.envs.ball_catcher.layout import BALL
from observer_gym.envs.target_follower import StateIndex
from observer_gym.estimation.ball_catcher.frames import FrameReader as BCFrameReader
from observer_gym.estimation.ball_catcher.learned import TRAINING_RANGES as BC_TRAINING_RANGES
from observer_gym.estimation.ball_catcher.learned import LearnedFeatures as BCLearnedFeatures
from observer_gym.estimation.ball_catcher.learned import image_centre_px
from observer_gym.estimation.ball_catcher.state_layout import state_estimate as bc_state_estimate
from observer_gym.estimation.ball_table.learned import (
    ACTION_NOISE_RAD,
    TRAINING_RANGES,
    LearnedFeatures,
)
from observer_gym.estimation.target_follower.frames import FrameReader
from observer_gym.estimation.target_follower.learned import N_OUT as TF_N_OUT
from observer_gym.estimation.target_follower.learned import TRAINING_RANGES as TF_TRAINING_RANGES
from observer_gym.estimation.target_follower.learned import LearnedEstimator as TFLearnedEstimator
from observer_gym.estimation.target_follower.learned_detector import (
    ACTION_NOISE as TF_ACTION_NOISE,
)
from observer_gym.estimation.target_follower.state_layout import RobotStep
from observer_gym.train.experiments.learned_observers import (
    ball_catcher,
    ball_table,
    target_follower,
)
from observer_gym.train.experiments.learned_observers.recorded import training_arrays
from observer_gym.train.reports.dataset import read_recording


def frozen_ball_table_collect(
    episodes: int, seed: int, steps: int, act_with: Any = None
) -> tuple[Any, Any, Any]:
    """BallTable's ``collect`` as it was before it recorded: its own loop over envs made
    per episode, the arrays kept in memory (frozen copy)."""
    rng = np.random.default_rng(seed)
    xs, ys, eps = [], [], []
    for episode in range(episodes):
        options = {key: float(rng.uniform(*bounds)) for key, bounds in TRAINING_RANGES.items()}
        env = gym.make("observer_gym/BallTable-v0", obs_mode="measurements", **options)
        try:
            controller = make_controller("lqr", env)
            box: Any = env.action_space
            features = LearnedFeatures()
            obs, info = env.reset(seed=int(rng.integers(2**31)))
            action = None
            for _ in range(steps):
                capture_s = features.newest_capture_s(info)
                if capture_s is not None:
                    features.new_frame(obs, capture_s)
                xs.append(features.vector(float(info["time_s"]), action))
                ys.append(np.asarray(info["state"], dtype=float))
                eps.append(episode)
                if act_with is None:
                    acted_on = info["state"]
                else:
                    acted_on, _ = act_with.predict(xs[-1])
                planned, _ = controller.predict(acted_on, deterministic=True)
                noise = rng.normal(0.0, ACTION_NOISE_RAD, 2)
                action = np.clip(planned + noise, box.low, box.high)
                obs, _, terminated, truncated, info = env.step(action.astype(np.float32))
                if terminated or truncated:
                    break
        finally:
            env.close()
    return np.array(xs), np.array(ys), np.array(eps)


def test_ball_table_arrays_from_a_recording_equal_the_old_collection(tmp_path):
    episodes, seed, steps = 2, 7, 20
    old_x, old_y, old_episode = frozen_ball_table_collect(episodes, seed, steps)
    record = ball_table.record_episodes(tmp_path / "data", episodes, seed, steps)
    x, y, episode = training_arrays("BallTable-v0", tmp_path / "data")
    assert x.shape == old_x.shape == (episodes * steps, 58)
    # the truth, the episode and every feature but the last action: bit for bit
    np.testing.assert_array_equal(y, old_y)
    np.testing.assert_array_equal(episode, old_episode)
    np.testing.assert_array_equal(x[:, :-2], old_x[:, :-2])
    # the last action: as it reached the env (float32), the old one unrounded (float64)
    np.testing.assert_array_equal(x[:, -2:], old_x[:, -2:].astype(np.float32))
    assert not np.array_equal(x[:, -2:], old_x[:, -2:])  # the rounding is real
    # each episode's drawn options are in the recording, within the declared ranges
    recorded = read_recording(tmp_path / "data")
    for played, kept in zip(record["episodes"], recorded, strict=True):
        assert kept.seed == played["seed"]
        assert kept.drawn_options == pytest.approx(played["drawn_options"])
        assert set(kept.drawn_options) == set(TRAINING_RANGES)
        for key, value in kept.drawn_options.items():
            low, high = TRAINING_RANGES[key]
            assert low <= value <= high
    assert len({tuple(sorted(e.drawn_options.items())) for e in recorded}) == episodes


def frozen_target_follower_collect(
    episodes: int, seed: int, steps: int, act_with: Any = None
) -> tuple[Any, Any, Any]:
    """TargetFollower's ``collect`` as it was before it recorded (frozen copy)."""
    rng = np.random.default_rng(seed)
    noise_std = np.asarray(TF_ACTION_NOISE)
    xs, ys, eps = [], [], []
    for episode in range(episodes):
        options = {key: float(rng.uniform(*b)) for key, b in TF_TRAINING_RANGES.items()}
        env = gym.make("observer_gym/TargetFollower-v0", obs_mode="measurements", **options)
        try:
            base: Any = env.unwrapped
            controller = make_controller("vtc", env)
            low, high = env.action_space.low, env.action_space.high  # type: ignore[attr-defined]
            frames = FrameReader(base, owner="collect")
            estimator = TFLearnedEstimator(act_with)
            delta_y_m = base.calibration["delta_y_m"]
            obs, info = env.reset(seed=int(rng.integers(2**31)))
            action = None
            for _ in range(steps):
                robot = RobotStep.from_info(info, action, delta_y_m)
                frame = frames.newest(obs, info)
                truth = np.asarray(info["state"], dtype=float)
                if act_with is None:
                    estimator.features.add(frame, robot)
                    acted_on = truth
                else:
                    acted_on, _, _ = estimator.step(frame, robot)
                if truth[StateIndex.TRACKING_VALID] >= 0.5 and estimator.features.any_detected:
                    xs.append(estimator.features.vector(robot.time_s))
                    ys.append(truth[:TF_N_OUT])
                    eps.append(episode)
                with warnings.catch_warnings():  # the VTC's first singular stop warns
                    warnings.simplefilter("ignore", RuntimeWarning)
                    planned, _ = controller.predict(acted_on, deterministic=True)
                action = np.clip(planned + rng.normal(0.0, noise_std), low, high)
                obs, _, terminated, truncated, info = env.step(action.astype(np.float32))
                if terminated or truncated:
                    break
        finally:
            env.close()
    return np.array(xs), np.array(ys), np.array(eps)


def test_target_follower_arrays_from_a_recording_equal_the_old_collection(tmp_path):
    episodes, seed, steps = 2, 5, 30
    old = frozen_target_follower_collect(episodes, seed, steps)
    target_follower.record_episodes(tmp_path / "data", episodes, seed, steps)
    new = training_arrays("TargetFollower-v0", tmp_path / "data")
    assert len(old[0]) > 20 and set(old[2]) == {0, 1}  # both episodes tracked the target
    for found, expected in zip(new, old, strict=True):  # bit for bit, every array
        assert found.shape == expected.shape
        np.testing.assert_array_equal(found, expected)


def frozen_ball_catcher_collect(
    episodes: int, seed: int, act_with: Any = None
) -> tuple[Any, Any, Any]:
    """BallCatcher's ``collect`` as it was before it recorded, with its own draw of the
    options (frozen copy)."""
    rng = np.random.default_rng(seed)
    xs, ys, eps = [], [], []
    for episode in range(episodes):
        options: dict[str, Any] = {}
        for key, values in BC_TRAINING_RANGES.items():
            if all(isinstance(v, str) for v in values):
                options[key] = values[int(rng.integers(len(values)))]
            else:
                options[key] = float(rng.uniform(*values))
        env = gym.make("observer_gym/BallCatcher-v1", obs_mode="measurements", **options)
        try:
            unwrapped: Any = env.unwrapped
            controller = make_controller("intercept", env)
            pixels = BCFrameReader(unwrapped.config, owner="collect")
            features = BCLearnedFeatures(unwrapped.num_cameras, image_centre_px(unwrapped))
            _, info = env.reset(seed=int(rng.integers(2**31)))
            while True:
                for frame in info["frames"]:
                    uv = pixels.detect(frame)
                    features.add(int(frame["camera_id"]), float(frame["capture_time_s"]), uv)
                x = features.vector(float(info["time_s"]))
                if info["ball_in_flight"]:
                    xs.append(x)
                    ys.append(np.asarray(info["state"][BALL], dtype=float))
                    eps.append(episode)
                if act_with is None:
                    acted_on = np.asarray(info["state"], dtype=float)
                else:
                    ball, ball_covariance = act_with.predict(x)
                    acted_on, covariance = bc_state_estimate(ball, ball_covariance, info)
                    controller.observe_info({"estimate": {"covariance": covariance}})
                action, _ = controller.predict(acted_on, deterministic=True)
                _, _, terminated, truncated, info = env.step(action)
                if terminated or truncated:
                    break
        finally:
            env.close()
    return np.array(xs), np.array(ys), np.array(eps)


def test_ball_catcher_arrays_from_a_recording_equal_the_old_collection(tmp_path):
    old = frozen_ball_catcher_collect(2, 9)
    record = ball_catcher.record_episodes(tmp_path / "data", 2, 9)
    new = training_arrays("BallCatcher-v1", tmp_path / "data")
    assert len(old[0]) > 50 and set(old[2]) == {0, 1}
    # a camera preset (text choices) drawn per episode too
    assert {e["drawn_options"]["camera_preset"] for e in record["episodes"]} <= set(
        BC_TRAINING_RANGES["camera_preset"]
    )
    for found, expected in zip(new, old, strict=True):  # bit for bit, every array
        assert found.shape == expected.shape
        np.testing.assert_array_equal(found, expected)


@pytest.mark.parametrize("system", ["ball_table", "target_follower", "ball_catcher"])
def test_a_dagger_rounds_arrays_equal_the_old_collections(tmp_path, system):
    """The network acting (the shipped one): the recording's player acts as the earlier
    collection did, so the arrays are the same (BallTable's action feature as float32)."""
    pytest.importorskip("torch")
    import importlib

    from observer_gym.estimation.learned.network import load_network

    net, _ = load_network(
        importlib.import_module(f"observer_gym.estimation.{system}.learned").WEIGHTS
    )
    out = tmp_path / "data"
    module = {
        "ball_table": ball_table,
        "target_follower": target_follower,
        "ball_catcher": ball_catcher,
    }[system]
    if system == "ball_catcher":
        old = frozen_ball_catcher_collect(1, 4, act_with=net)
        module.record_episodes(out, 1, 4, act_with=net)
    else:
        frozen = {
            "ball_table": frozen_ball_table_collect,
            "target_follower": frozen_target_follower_collect,
        }[system]
        old = frozen(2, 4, 25, act_with=net)
        module.record_episodes(out, 2, 4, 25, act_with=net)
    env_id = {
        "ball_table": "BallTable-v0",
        "target_follower": "TargetFollower-v0",
        "ball_catcher": "BallCatcher-v1",
    }[system]
    new = training_arrays(env_id, out)
    assert len(old[0]) > 10
    if system == "ball_table":
        np.testing.assert_array_equal(new[0][:, :-2], old[0][:, :-2])
        np.testing.assert_array_equal(new[0][:, -2:], old[0][:, -2:].astype(np.float32))
        new, old = new[1:], old[1:]
    for found, expected in zip(new, old, strict=True):
        np.testing.assert_array_equal(found, expected)


def test_training_arrays_refuse_another_systems_recording(tmp_path):
    ball_table.record_episodes(tmp_path / "data", 1, 0, 2)
    with pytest.raises(ValueError, match="holds a recording of BallTable-v0 in obs mode"):
        training_arrays("TargetFollower-v0", tmp_path / "data")


def test_training_arrays_refuse_another_recording(tmp_path):
    with pytest.raises(ValueError, match="no reader of recorded training data for Nope-v0"):
        training_arrays("Nope-v0", tmp_path)
    with pytest.raises(ValueError, match="holds no recording"):
        training_arrays("BallTable-v0", tmp_path)


@pytest.mark.slow  # a recording and a fit: about 7 s
def test_a_tiny_training_from_a_dataset_runs_end_to_end(tmp_path, capsys):
    pytest.importorskip("torch")
    from observer_gym.estimation.learned.network import checked_report
    from observer_gym.train.experiments.learned_observers import train

    ball_table.record_episodes(tmp_path / "data", 5, 3, 20)
    out = tmp_path / "net.pt"
    argv = ["--env", "BallTable-v0", "--episodes", "5", "--rounds", "1", "--epochs", "1"]
    assert train.main([*argv, "--dataset", str(tmp_path / "data"), "--out", str(out)]) == 0
    report = checked_report(out)
    assert report["samples"] == 5 * 20  # every recorded step a sample
    assert report["command"].endswith(f"--dataset {tmp_path / 'data'}")
    assert "data" not in report  # nothing recorded: one round, read from the dataset
    assert out.is_file()


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (
            ["--env", "BallCatcher-v1", "--dataset", "nothing-here"],
            "holds no recording",
        ),
        (["--env", "BallTable-v0", "--dataset", "nothing-here"], "holds no recording"),
    ],
)
def test_train_refuses_a_dataset_in_one_line(tmp_path, capsys, monkeypatch, extra, message):
    pytest.importorskip("torch")
    from observer_gym.train.experiments.learned_observers import train

    monkeypatch.chdir(tmp_path)
    assert train.main([*extra, "--rounds", "1", "--out", str(tmp_path / "n.pt")]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert not (tmp_path / "n.pt").exists()


@pytest.mark.slow  # a DAgger round of 5 whole episodes recorded with the network acting: ~15 s
def test_a_dagger_round_is_recorded_into_the_data_folder(tmp_path):
    pytest.importorskip("torch")
    from observer_gym.estimation.learned.network import checked_report
    from observer_gym.train.experiments.learned_observers import train

    ball_table.record_episodes(tmp_path / "first", 5, 3, 20)
    out, data = tmp_path / "net.pt", tmp_path / "data"
    argv = ["--env", "BallTable-v0", "--episodes", "5", "--rounds", "2", "--epochs", "1"]
    argv += ["--dataset", str(tmp_path / "first"), "--data", str(data), "--out", str(out)]
    assert train.main(argv) == 0
    report = checked_report(out)
    recorded = read_recording(data / "round-2")  # round 1 came from --dataset
    assert not (data / "round-1").exists()
    assert len(recorded) == 5 and report["data"] == str(data)
    assert report["samples"] == 5 * 20 + sum(len(e.actions) for e in recorded)
    x, _, _ = training_arrays("BallTable-v0", data / "round-2")
    assert len(x) == sum(len(e.actions) for e in recorded)
    # round 2 (k = 1) drew its sensors from the generator of --seed (0) + 1
    rng = np.random.default_rng(0 + 1)
    first = {key: float(rng.uniform(*bounds)) for key, bounds in TRAINING_RANGES.items()}
    assert recorded[0].drawn_options == first
    # a second run into the same data folder is refused in one line, before any episode
    assert train.main([*argv[:-2], "--out", str(tmp_path / "again.pt")]) == 2
    assert not (tmp_path / "again.pt").exists()


def test_ball_catchers_reader_refuses_more_frames_of_one_camera_than_recorded(tmp_path):
    from observer_gym.train.experiments.learned_observers.recorded import ball_catcher_arrays
    from observer_gym.train.reports.dataset import RecordedEpisode

    ball_catcher.record_episodes(tmp_path / "data", 1, 2)
    (episode,) = read_recording(tmp_path / "data")
    config = {"env_kwargs": {"obs_mode": "measurements"}}
    assert len(ball_catcher_arrays([episode], config)[0]) > 0  # as recorded: read
    counts = episode.infos["frame_count"].copy()
    step = int(np.flatnonzero(counts[:, 0])[0])
    counts[step, 0] = 3  # as if camera 0 had delivered three frames at that step
    tripled = RecordedEpisode(
        **{**vars(episode), "infos": {**episode.infos, "frame_count": counts}}
    )
    with pytest.raises(ValueError, match=f"step {step} delivered 3 frames of one camera; "):
        ball_catcher_arrays([tripled], config)
    # a recording made before the earlier frame was kept: two frames are refused
    counts[step, 0] = 2
    infos = {k: v for k, v in episode.infos.items() if not k.startswith("frame_earlier")}
    doubled = RecordedEpisode(**{**vars(episode), "infos": {**infos, "frame_count": counts}})
    with pytest.raises(ValueError, match=f"step {step} delivered 2 frames .* 1 newest only"):
        ball_catcher_arrays([doubled], config)
