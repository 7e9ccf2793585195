"""The pretrained frame encoder of rgb agents: the pixel-coordinate channels, fitting on
synthetic frames, saving and loading, the env checks, the command's mistakes, and the
shipped BallTable encoder against the simulator's ground truth."""

from __future__ import annotations

import json
import shutil
import warnings

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.wrappers import FrameStackObservation

from observer_gym.controllers.registry import make_controller
from observer_gym.train.rl.agent import Agent
from observer_gym.train.rl.agent_env import make_agent_env
from observer_gym.train.rl.pixel_encoder import (
    ENCODERS_DIR,
    EncodedFrames,
    Encoder,
    FrameEncoderNet,
    ImageCoordinates,
    StackDifferences,
    encoder_path,
    encoder_sha256,
    load_encoder,
)
from observer_gym.train.rl.pretrain_encoder import _without_option, fit_encoder, main
from observer_gym.train.rl.run_dir import write_config
from observer_gym.train.rl.shipped import shipped_path


def test_coordinate_channels_hold_each_pixels_position():
    images = torch.zeros(2, 1, 3, 5)
    out = ImageCoordinates()(images)
    assert out.shape == (2, 3, 3, 5)
    np.testing.assert_allclose(out[1, 1, 2].numpy(), [-1.0, -0.5, 0.0, 0.5, 1.0])  # x
    np.testing.assert_allclose(out[0, 2, :, 4].numpy(), [-1.0, 0.0, 1.0])  # y


def test_stack_differences_are_the_newest_vector_and_its_steps():
    stacked = gym.make("observer_gym/BallTable-v0", obs_mode="state")
    try:
        wrapper = StackDifferences(FrameStackObservation(stacked, 3))
        stack = np.array([[1.0, 10.0], [2.0, 30.0], [4.0, 70.0]])  # oldest first
        np.testing.assert_array_equal(
            wrapper.observation(stack), [[4.0, 70.0], [2.0, 40.0], [1.0, 20.0]]
        )
        assert wrapper.observation_space.shape == (3, 8)
    finally:
        stacked.close()


def _square_frames(n: int, rng: np.random.Generator, size: int = 48):
    """Frames (n, 1, size, size) of a white 8-px square on black at a position uniform in
    the image; targets: its centre in pixels."""
    frames = np.zeros((n, 1, size, size), np.uint8)
    centres = rng.uniform(6, size - 7, size=(n, 2)).round()
    for k, (x, y) in enumerate(centres.astype(int)):
        frames[k, :, y - 4 : y + 4, x - 4 : x + 4] = 255
    return frames, centres.astype(np.float32)


def test_fitting_locates_a_square_to_a_pixel():
    """Fitted on 2,000 synthetic frames for 10 epochs, the held-out error of the square's
    position is below one pixel (its standard deviation is about 10 px)."""
    torch.set_num_threads(1)
    frames, centres = _square_frames(2000, np.random.default_rng(0))
    episodes = np.arange(len(frames))
    _, record = fit_encoder(frames, centres, episodes, epochs=10, seed=0)
    assert record["held_out_frames"] == 200
    rmse = np.array(record["history"][-1]["rmse"])
    assert centres.std(axis=0).min() > 9.0
    assert np.all(rmse < 1.0), rmse


def test_a_target_a_frame_does_not_show_is_left_out_of_the_fit_and_the_errors():
    """NaN targets (TargetFollower's position of a target off the image) count in neither
    the loss nor the held-out errors: with the position of one frame in three hidden,
    the fit still locates the square to a pixel, and the errors come out finite."""
    torch.set_num_threads(1)
    frames, centres = _square_frames(2000, np.random.default_rng(0))
    hidden = np.arange(len(frames)) % 3 == 0
    frames[hidden] = 0  # nothing to see
    targets = np.column_stack([centres, (~hidden).astype(np.float32)])
    targets[hidden, :2] = np.nan
    _, record = fit_encoder(frames, targets, np.arange(len(frames)), epochs=10, seed=0)
    rmse = np.array(record["history"][-1]["rmse"])
    assert np.all(np.isfinite(rmse)) and np.all(rmse[:2] < 1.0) and rmse[2] < 0.1, rmse


META = {
    "env_id": "observer_gym/BallTable-v0",
    "camera_px": [84, 84],
    "image": {"size_px": 84, "grayscale": True},
    "channels": 1,
    "targets": ["ball_x_m", "ball_y_m", "tilt_x_rad", "tilt_y_rad"],
}


def test_an_encoder_saves_and_loads_to_the_same_outputs(tmp_path):
    torch.manual_seed(0)
    net = FrameEncoderNet(1, 84, 4)
    net.target_std.fill_(0.5)
    Encoder(net, META).save(tmp_path / "e.pt")
    assert json.loads((tmp_path / "e.json").read_text())["targets"] == META["targets"]
    frames = np.random.default_rng(1).integers(0, 255, (3, 1, 84, 84), dtype=np.uint8)
    loaded = load_encoder(str(tmp_path / "e.pt"))
    np.testing.assert_array_equal(loaded(frames), Encoder(net, META)(frames))
    np.testing.assert_allclose(loaded(frames[0]), loaded(frames)[0], rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match="neither a shipped encoder"):
        encoder_path(str(tmp_path / "missing.pt"))


def test_an_encoder_refuses_another_camera():
    encoder = Encoder(FrameEncoderNet(1, 84, 4), META)
    env = make_agent_env("observer_gym/BallTable-v0", "rgb", image={"frame_stack": 1})
    try:  # a 320 x 240 camera
        with pytest.raises(ValueError, match="trained on observer_gym/BallTable-v0 with camera"):
            EncodedFrames(env, encoder)
    finally:
        env.close()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--env", "BallCatcher-v1", "--out", "x.pt"], "no pixel encoder for BallCatcher-v1"),
        (["--env", "BallTable-v0", "--out", "x.npz"], "--out must name a .pt file"),
        (["--env", "BallTable-v0", "--out", "x.pt", "--frames", "0"], "--frames"),
    ],
)
def test_the_command_reports_a_mistake_in_one_line(argv, message, capsys, tmp_path):
    argv = [a if a not in ("x.pt", "x.npz") else str(tmp_path / a) for a in argv]
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own checks (the Parser's one line)
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1
    assert not list(tmp_path.iterdir())


def test_frames_kept_for_other_arguments_are_refused(capsys, tmp_path):
    data = tmp_path / "frames.npz"
    np.savez(data, frames=np.zeros((8, 1, 84, 84), np.uint8), collected_with=np.array("[]"))
    before = data.read_bytes()
    out = tmp_path / "encoder.pt"
    code = main(["--env", "BallTable-v0", "--out", str(out), "--frames", "8", "--data", str(data)])
    err = capsys.readouterr().err
    assert code == 2 and "holds frames collected with" in err and err.count("\n") == 1
    assert data.read_bytes() == before and not out.exists()


def test_the_recorded_command_leaves_out_where_the_frames_were_kept():
    words = ["--env", "BallTable-v0", "--data", "/x/frames.npz", "--seed", "1", "--data=y.npz"]
    assert _without_option(words, "--data") == ["--env", "BallTable-v0", "--seed", "1"]


@pytest.mark.skipif(
    not (ENCODERS_DIR / "ball_table.pt").is_file(), reason="no shipped BallTable encoder"
)
# rendered frames through the shipped encoder (3.6 s idle): slow
@pytest.mark.slow
def test_the_shipped_ball_table_encoder_reads_the_ball_from_fresh_frames():
    """On frames it never saw (a new seed, LQR on the truth with noise), with the ball
    within 3 cm of the centre, the encoder's ball position is within 2x its report's
    held-out RMSE there of the truth, and that RMSE is below 5 mm."""
    encoder = load_encoder("ball_table")
    reported = encoder.meta["held_out_rmse_near_centre"]
    reported = np.array([reported["ball_x_m"], reported["ball_y_m"]])
    assert np.all(reported < 0.005)
    env = make_agent_env(
        "observer_gym/BallTable-v0", "rgb", env_kwargs=encoder.meta["env_kwargs"],
        image={**encoder.meta["image"], "frame_stack": 1, "encoder": "ball_table"},
    )  # fmt: skip
    errors = []
    try:
        lqr = make_controller("lqr", env)
        high = env.unwrapped.action_space.high
        rng = np.random.default_rng(7)
        for episode in range(2):
            estimate, info = env.reset(seed=12345 + episode)
            for _ in range(250):
                if np.abs(info["state"][:2]).max() < 0.03:
                    errors.append(estimate[:2] - info["state"][:2])
                action, _ = lqr.predict(info["state"][None], deterministic=True)
                action = np.asarray(action).reshape(-1) / high + rng.normal(0.0, 0.3, 2)
                estimate, _, terminated, truncated, info = env.step(
                    np.clip(action, -1, 1).astype(np.float32)
                )
                if terminated or truncated:
                    break
    finally:
        env.close()
    rmse = np.sqrt(np.mean(np.square(errors), axis=0))
    assert len(errors) > 200
    assert np.all(rmse < 2 * reported), (rmse, reported)


@pytest.mark.skipif(
    not (ENCODERS_DIR / "target_follower.pt").is_file(), reason="no shipped TargetFollower encoder"
)
def test_the_shipped_target_follower_encoder_reads_the_target_from_fresh_frames():
    """On frames it never saw (new seeds, the VTC on the truth with noise, the occluder of
    its data walking in), with the target seen within 1/16 of the image width of the
    centre, the encoder's (x_i, y_i, d_x) is within 2x its report's held-out RMSE there of
    the truth (that RMSE below 1 px of its 84 x 63 camera), and its visibility output
    says on which frames the target is seen (above 0.5 on >= 95 % of the frames)."""
    encoder = load_encoder("target_follower")
    names = ("x_i_px", "y_i_px", "d_x_px")
    reported = np.array([encoder.meta["held_out_rmse_near_centre"][k] for k in names])
    assert np.all(reported < 1.0), reported
    bound = encoder.meta["near_centre"]["bound"]
    env = make_agent_env(
        "observer_gym/TargetFollower-v0", "rgb", env_kwargs=encoder.meta["env_kwargs"],
        image={**encoder.meta["image"], "frame_stack": 1, "encoder": "target_follower"},
    )  # fmt: skip
    errors, agree = [], []
    try:
        vtc = make_controller("vtc", env)
        high = env.unwrapped.action_space.high
        rng = np.random.default_rng(7)
        for episode in range(2):
            estimate, info = env.reset(seed=12345 + episode)
            for _ in range(150):
                state = info["state"]
                agree.append((estimate[3] > 0.5) == (state[14] > 0.5))
                if state[14] > 0.5 and np.abs(state[:2]).max() < bound:
                    errors.append(estimate[:3] - state[:3])
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)  # a singular B_i
                    action, _ = vtc.predict(state[None], deterministic=True)
                action = np.asarray(action).reshape(-1) / high + rng.normal(0.0, 0.1, 3)
                estimate, _, terminated, truncated, info = env.step(
                    np.clip(action, -1, 1).astype(np.float32)
                )
                if terminated or truncated:
                    break
    finally:
        env.close()
    rmse = np.sqrt(np.mean(np.square(errors), axis=0))
    assert len(errors) > 100 and np.mean(agree) >= 0.95, (len(errors), np.mean(agree))
    assert np.all(rmse < 2 * reported), (rmse, reported)


def test_an_agent_refuses_an_encoder_that_changed(tmp_path):
    """The shipped rgb agent records its encoder's sha256; a copy whose record differs
    from the file the name points to is refused on loading."""
    shipped = shipped_path("ball_table-rgb")
    assert Agent.load(shipped).config["encoder_sha256"] == encoder_sha256("ball_table")
    copy = tmp_path / "agent"
    shutil.copytree(shipped, copy)
    config = json.loads((copy / "config.json").read_text())
    config["encoder_sha256"] = "0" * 64
    write_config(copy, config)  # a consistent config.json that names another encoder
    with pytest.raises(ValueError, match="trained with another image encoder 'ball_table'"):
        Agent.load(copy)
