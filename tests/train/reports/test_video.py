"""``--video``: the MP4s of episodes (train/reports/video.py), decoded with OpenCV.

What a written video must show: one frame per delivered frame, the estimate's overlay at
the pixel the estimate projects to, the truth through the true camera; what it must not
do: change the episode's numbers, leave a half-written file behind (an error, Ctrl-C, a
full disk), or run without its extra or on an observer that reads no images.
"""

from __future__ import annotations

import importlib.util
import json
import os
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

pytest.importorskip("imageio_ffmpeg")

from observer_gym.envs import system_for_id
from observer_gym.train.cli import main
from observer_gym.train.core.observer_env import make_env, resolve_observer
from observer_gym.train.experiments.episode import (
    EpisodeSpec,
    build_controller,
    run_episode,
)
from observer_gym.train.experiments.request import resolve_controller
from observer_gym.train.reports import video as video_module
from observer_gym.train.reports.episode_frames import (
    marker_pixels,
    projection_for,
)
from observer_gym.train.reports.video import EpisodeVideo, VideoRequest

ENV = "observer_gym/BallTable-v0"
SYSTEM = system_for_id(ENV)


def decoded(path: Path) -> list[np.ndarray]:
    """Every frame of the MP4 ``path``, RGB."""
    capture = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, frame = capture.read()
        if not ok:
            break
        frames.append(cv2.cvtColor(frame, cv2.COLOR_BGR2RGB))
    capture.release()
    return frames


def film(folder: Path, steps: int, env_options: dict | None = None):
    """A BallTable kf + lqr episode of ``steps`` steps filmed into ``folder``: the video's
    path, the number of frames delivered, and the last frame's info."""
    env = make_env(SYSTEM, resolve_observer(SYSTEM, "kf"), env_options)
    try:
        controller = build_controller(resolve_controller(SYSTEM, "lqr"), env, SYSTEM)
        controller.reset()
        video = EpisodeVideo(VideoRequest(str(folder), "episode"), env)
        with video:
            obs, info = env.reset(seed=3)
            video.add(info, 0)
            delivered = len(info["frames"])
            last = info
            for step in range(1, steps + 1):
                action, _ = controller.predict(obs)
                obs, _, _, _, info = env.step(action)
                video.add(info, step, action)
                delivered += len(info["frames"])
                if info["frames"]:
                    last = info
        return video.paths[0], delivered, last
    finally:
        env.close()


def near(pixel: np.ndarray, colour: tuple[int, int, int], tolerance: int = 70) -> bool:
    return bool(np.all(np.abs(pixel.astype(int) - np.array(colour)) <= tolerance))


def test_the_video_has_one_frame_per_delivered_frame_and_the_estimate_where_it_projects(
    tmp_path,
):
    path, delivered, last = film(tmp_path, steps=30)
    frames = decoded(path)
    assert len(frames) == delivered
    assert path.name == "episode.mp4"
    assert [p.name for p in tmp_path.iterdir()] == ["episode.mp4"]  # no temp left
    env = make_env(SYSTEM, resolve_observer(SYSTEM, "kf"))
    try:
        projection = projection_for(env)
    finally:
        env.close()
    assert projection is not None
    frame_info = last["frames"][-1]
    estimate = marker_pixels(
        projection, last["estimate"]["mean"], frame_info["K"], frame_info["T_world_cam"]
    )
    assert estimate is not None
    scale = 2  # a 320 x 240 frame is doubled in the video
    u, v = np.round(estimate.uv_px * scale).astype(int)
    image = frames[-1]
    assert near(image[v, u], video_module.ESTIMATE_RGB), image[v, u]
    # and not by chance: the scene has no magenta (the ball is green, the table red)
    assert not near(frames[-1][v, u + 12], video_module.ESTIMATE_RGB)


def test_the_truth_through_the_true_camera_and_the_nominal_one_differ_with_a_calibration_error(
    tmp_path,
):
    options = {"calib_principal_point_error_px": 20.0, "calib_error_draw": "fixed"}
    path, delivered, last = film(tmp_path, steps=10, env_options=options)
    frames = decoded(path)
    assert len(frames) == delivered
    env = make_env(SYSTEM, resolve_observer(SYSTEM, "kf"), options)
    try:
        projection = projection_for(env)
    finally:
        env.close()
    assert projection is not None
    nominal, true = last["frames"][-1], last["truth"]["frames"][-1]
    through_true = marker_pixels(projection, last["state"], true["K"], true["T_world_cam"])
    through_nominal = marker_pixels(projection, last["state"], nominal["K"], nominal["T_world_cam"])
    assert through_true is not None and through_nominal is not None
    assert np.linalg.norm(through_true.uv_px - through_nominal.uv_px) > 15.0  # px
    # the truth's cross at the true camera's pixel (on its arm, clear of the estimate's dot)
    u, v = np.round(through_true.uv_px * 2).astype(int)
    arm = video_module.ESTIMATE_DOT_PX + 4
    image = frames[-1]
    assert near(image[v, u + arm], video_module.TRUTH_RGB), image[v, u + arm]


def test_dropped_frames_are_marked_on_the_next_frame(tmp_path):
    env = make_env(SYSTEM, resolve_observer(SYSTEM, "kf"), {"frame_drop_prob": 0.3})
    captures = []
    try:
        controller = build_controller(resolve_controller(SYSTEM, "lqr"), env, SYSTEM)
        controller.reset()
        with EpisodeVideo(VideoRequest(str(tmp_path), "drops"), env) as video:
            obs, info = env.reset(seed=1)
            video.add(info, 0)
            captures += [f["capture_time_s"] for f in info["frames"]]
            for step in range(1, 41):
                action, _ = controller.predict(obs)
                obs, _, _, _, info = env.step(action)
                video.add(info, step, action)
                captures += [f["capture_time_s"] for f in info["frames"]]
    finally:
        env.close()
    frames = decoded(tmp_path / "drops.mp4")
    assert len(frames) == len(captures)
    period_s = 1 / 50
    after_drop = [
        k for k in range(1, len(captures)) if captures[k] - captures[k - 1] > 1.5 * period_s
    ]
    assert after_drop and len(after_drop) < len(captures) - 1  # some frames dropped, not all
    height = frames[0].shape[0]
    # the red border's bottom-left corner, on the frames after a drop and only there
    marked = [
        k for k, frame in enumerate(frames) if near(frame[height - 2, 1], video_module.DROPPED_RGB)
    ]
    assert marked == after_drop


def test_recording_changes_nothing_in_the_episode(tmp_path):
    spec = EpisodeSpec.of(ENV, "kf", "lqr", seed=5, max_steps=25)
    plain = run_episode(spec)
    filmed = run_episode(
        EpisodeSpec.of(
            ENV, "kf", "lqr", seed=5, max_steps=25, video=VideoRequest(str(tmp_path), "x")
        )
    )
    for key in ("time_s", "state", "estimate", "estimate_std", "actions", "rewards", "nees"):
        np.testing.assert_array_equal(plain[key], filmed[key], err_msg=key)
    assert len(decoded(tmp_path / "x.mp4")) == 26  # 50 Hz frames, 50 Hz steps, and the reset's


def test_ctrl_c_mid_episode_leaves_no_file(tmp_path, monkeypatch):
    calls = {"n": 0}
    add = EpisodeVideo.add

    def interrupted(self, info, step, action=None):
        add(self, info, step, action)
        calls["n"] += 1
        if calls["n"] == 6:
            raise KeyboardInterrupt

    monkeypatch.setattr(EpisodeVideo, "add", interrupted)
    spec = EpisodeSpec.of(
        ENV, "kf", "lqr", seed=0, max_steps=20, video=VideoRequest(str(tmp_path), "x")
    )
    with pytest.raises(KeyboardInterrupt):
        run_episode(spec)
    assert calls["n"] == 6  # frames had gone to the encoder
    assert list(tmp_path.iterdir()) == []  # neither the video nor its temp


def test_a_full_disk_is_one_write_error_and_leaves_no_file(tmp_path, monkeypatch):
    import imageio_ffmpeg

    real = imageio_ffmpeg.write_frames

    def full_disk(path, *args, **kwargs):
        writer = real(path, *args, **kwargs)
        sent = {"n": 0}

        def generator():
            writer.send(None)  # starts ffmpeg, as the writer's first send does
            frame = yield
            while True:
                sent["n"] += 1
                if sent["n"] > 3:
                    writer.close()
                    raise OSError(28, "No space left on device")
                writer.send(frame)
                frame = yield

        wrapped = generator()
        return wrapped

    monkeypatch.setattr(imageio_ffmpeg, "write_frames", full_disk)
    spec = EpisodeSpec.of(
        ENV, "kf", "lqr", seed=0, max_steps=10, video=VideoRequest(str(tmp_path), "x")
    )
    with pytest.raises(OSError, match=r"could not write .*x\.mp4: .*No space left"):
        run_episode(spec)
    assert list(tmp_path.iterdir()) == []


def test_a_temp_left_by_a_killed_run_is_removed_by_the_next(tmp_path):
    from observer_gym.train.reports.outputs import OutputFolderWarning
    from observer_gym.train.reports.video import check_video_folder

    dead = tmp_path / ".x.mp4.tmp-999999999"  # no such process
    alive = tmp_path / f".y.mp4.tmp-{os.getpid()}"  # this one's: still writing
    dead.write_bytes(b"half")
    alive.write_bytes(b"half")
    with pytest.warns(OutputFolderWarning, match=r"removed 1 temp file\(s\)"):
        check_video_folder(tmp_path)
    assert not dead.exists() and alive.exists()


def one_line_error(capsys, argv: list[str]) -> tuple[int, str]:
    code = main(argv)
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    return code, err


def test_an_observer_without_images_is_refused_naming_rgb(tmp_path, capsys):
    argv = ["run", "--observer", "kf-measurements", "--controller", "lqr", "--episodes", "1"]
    code, err = one_line_error(capsys, [*argv, "--out", str(tmp_path / "r"), "--video", "v"])
    assert code == 2
    assert "'kf-measurements' reads measurements" in err and "obs_mode 'rgb'" in err
    assert not (tmp_path / "r").exists()


def test_bad_video_episodes_are_refused(tmp_path, capsys):
    argv = ["run", "--observer", "kf", "--controller", "lqr", "--episodes", "2"]
    argv += ["--out", str(tmp_path / "r")]
    code, err = one_line_error(capsys, [*argv, "--video-episodes", "0"])
    assert code == 2 and "--video-episodes needs --video DIR" in err
    code, err = one_line_error(
        capsys, [*argv, "--video", str(tmp_path / "v"), "--video-episodes", "2"]
    )
    assert code == 2 and "outside the run's episodes 0..1" in err
    assert not (tmp_path / "r").exists()


def test_a_folder_that_cannot_be_written_is_refused_before_any_episode(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("")
    argv = ["run", "--observer", "kf", "--controller", "lqr", "--episodes", "1"]
    code, err = one_line_error(
        capsys, [*argv, "--out", str(tmp_path / "r"), "--video", str(blocker / "videos")]
    )
    assert code == 1 and f"cannot write videos into {blocker / 'videos'}" in err
    assert not (tmp_path / "r").exists()


def test_video_without_the_extra_names_the_extra(tmp_path, capsys, monkeypatch):
    real = importlib.util.find_spec

    def find_spec(name, *args, **kwargs):
        return None if name == "imageio_ffmpeg" else real(name, *args, **kwargs)

    monkeypatch.delitem(sys.modules, "imageio_ffmpeg", raising=False)
    monkeypatch.setattr(importlib.util, "find_spec", find_spec)
    argv = ["run", "--observer", "kf", "--controller", "lqr", "--episodes", "1"]
    code, err = one_line_error(
        capsys, [*argv, "--out", str(tmp_path / "r"), "--video", str(tmp_path / "v")]
    )
    assert code == 2
    assert "--video needs imageio-ffmpeg, which is not installed: " in err
    assert "pip install 'observer-gym[video]'" in err
    assert not (tmp_path / "v").exists() and not (tmp_path / "r").exists()


@pytest.mark.slow
def test_compare_with_and_without_video_gives_the_same_table(tmp_path, capsys):
    argv = ["compare", "--observers", "oracle,kf", "--controllers", "lqr", "--episodes", "2"]
    argv += ["--steps", "60", "--no-progress"]
    assert main([*argv, "--out", str(tmp_path / "plain")]) == 0
    assert main([*argv, "--out", str(tmp_path / "filmed"), "--video", str(tmp_path / "v")]) == 0
    capsys.readouterr()
    plain = json.loads((tmp_path / "plain" / "results.json").read_text())
    filmed = json.loads((tmp_path / "filmed" / "results.json").read_text())
    assert [p["episodes"] for p in plain["pairs"]] == [p["episodes"] for p in filmed["pairs"]]
    table = (tmp_path / "plain" / "table.csv").read_text()
    assert table == (tmp_path / "filmed" / "table.csv").read_text()
    # the oracle reads no images: only kf's first episode is filmed
    assert [p.name for p in (tmp_path / "v").iterdir()] == [
        "BallTable-v0_kf_lqr_episode0_seed0.mp4"
    ]
    assert len(decoded(tmp_path / "v" / "BallTable-v0_kf_lqr_episode0_seed0.mp4")) == 61


@pytest.mark.slow
def test_ball_catcher_gets_one_video_per_camera(tmp_path):
    import observer_gym

    observer_gym.run(
        "BallCatcher-v1", "kf", "intercept", episodes=1, steps=40,
        out_dir=tmp_path / "r", video_dir=tmp_path / "v",
    )  # fmt: skip
    names = sorted(p.name for p in (tmp_path / "v").iterdir())
    assert names == [
        "BallCatcher-v1_kf_intercept_episode0_seed0_camera0.mp4",
        "BallCatcher-v1_kf_intercept_episode0_seed0_camera1.mp4",
    ]
    for name in names:
        assert len(decoded(tmp_path / "v" / name)) > 5
