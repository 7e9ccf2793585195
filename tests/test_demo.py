"""``observer-gym demo``: the files it writes, the numbers in its summary, and its CLI."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from observer_gym.train.cli import main
from observer_gym.train.demo import CIRCLE_RADIUS_M, run_demo


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory) -> tuple[Path, dict]:
    out_dir = tmp_path_factory.mktemp("demo")
    summary = run_demo(out_dir, seconds=1.0, frame_every=10, progress=False)
    return out_dir, summary


def test_demo_writes_frames_plot_and_summary(demo_run):
    out_dir, summary = demo_run
    frames = sorted((out_dir / "frames").glob("frame_*.png"))
    # Steps 0, 10, ..., 50.
    assert [p.name for p in frames] == [f"frame_{i:04d}.png" for i in range(0, 51, 10)]
    for path in frames:
        image = cv2.imread(str(path))
        assert image is not None and image.shape == (240, 320, 3)
    plot = cv2.imread(str(out_dir / "trajectory.png"))
    assert plot is not None and plot.shape[0] > 100 and plot.shape[1] > 100
    for name in summary["files"]:
        assert (out_dir / name).is_file(), name
    assert not list(out_dir.glob("*.tmp")), "the atomic write left a temp file behind"


def test_demo_summary_numbers(demo_run):
    out_dir, returned = demo_run
    summary = json.loads((out_dir / "summary.json").read_text())
    assert summary == returned
    assert summary["env_id"] == "observer_gym/BallTable-v0"
    assert summary["steps"] == 50  # 1 s at 50 Hz
    assert summary["terminated"] is False
    trajectory = summary["trajectory"]
    ball_pos_m = np.array(trajectory["ball_pos_table_m"])
    assert ball_pos_m.shape == (51, 2)  # after reset and after every step
    assert trajectory["time_s"][-1] == pytest.approx(1.0)
    np.testing.assert_allclose(ball_pos_m[0], (CIRCLE_RADIUS_M, 0.0), atol=1e-3)
    distance_m = np.linalg.norm(ball_pos_m, axis=1)
    assert summary["final_ball_distance_m"] == pytest.approx(distance_m[-1])
    assert summary["mean_ball_distance_m"] == pytest.approx(distance_m.mean())
    assert 0.0 <= summary["mean_ball_distance_m"] <= 0.2
    # One second is 1.5 rad of the scripted circle: the ball has moved around it, not off it.
    assert ball_pos_m[-1, 1] > 0.03
    assert abs(distance_m[-1] - CIRCLE_RADIUS_M) < 0.03
    assert 0.0 < summary["max_abs_tilt_rad"] <= 0.1
    assert summary["mean_step_time_s"] > 0.0
    assert set(summary["versions"]) == {"observer-gym", "gymnasium", "pybullet", "numpy"}


def test_run_demo_rejects_bad_duration(tmp_path):
    with pytest.raises(ValueError, match="seconds"):
        run_demo(tmp_path, seconds=0.0, progress=False)


def test_cli_demo_help_exits_zero(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["demo", "--help"])
    assert exc.value.code == 0
    assert "--seconds" in capsys.readouterr().out


def test_cli_demo_rejects_negative_seconds(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["demo", "--seconds", "-1"])
    assert exc.value.code == 2
    assert "must be a positive number" in capsys.readouterr().err
