"""``observer-gym demo``: the files it writes, the numbers in its summary, and its CLI."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from observer_gym.train.cli import main
from observer_gym.train.experiments.demo import START_DISTANCE_M, run_demo
from observer_gym.train.reports.outputs import VERSIONED_PACKAGES

SECONDS = 2.0


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory) -> tuple[Path, dict]:
    out_dir = tmp_path_factory.mktemp("demo")
    summary = run_demo(out_dir, seconds=SECONDS, frame_every=25, progress=False)
    return out_dir, summary


def test_demo_writes_frames_plot_and_summary(demo_run):
    out_dir, summary = demo_run
    frames = sorted((out_dir / "frames").glob("frame_*.png"))
    # Steps 0, 25, ..., 100.
    assert [p.name for p in frames] == [f"frame_{i:04d}.png" for i in range(0, 101, 25)]
    for path in frames:
        image = cv2.imread(str(path))
        assert image is not None and image.shape == (240, 320, 3)
    plot = cv2.imread(str(out_dir / "trajectory.png"))
    assert plot is not None and plot.shape[0] > 100 and plot.shape[1] > 100
    for name in summary["files"]:
        assert (out_dir / name).is_file(), name
    assert not list(out_dir.glob("*.tmp")), "the atomic write left a temp file behind"


def test_demo_centres_the_ball_through_the_camera(demo_run):
    """Pixel observer + LQR from 0.1 m: within 1 cm after ~0.9 s (README), estimate
    errors of a fraction of a millimetre; the summary's numbers are the trajectory's."""
    out_dir, returned = demo_run
    summary = json.loads((out_dir / "summary.json").read_text())
    assert summary == returned
    assert summary["env_id"] == "observer_gym/BallTable-v0"
    assert summary["controller"] == "lqr"
    assert summary["steps"] == 100  # 2 s at 50 Hz
    assert summary["terminated"] is False
    trajectory = summary["trajectory"]
    truth, estimate = np.array(trajectory["state"]), np.array(trajectory["estimate"])
    assert truth.shape == estimate.shape == (101, 8)  # after reset and after every step
    assert trajectory["time_s"][-1] == pytest.approx(SECONDS)
    distance_m = np.linalg.norm(truth[:, 0:2], axis=1)
    assert distance_m[0] == pytest.approx(START_DISTANCE_M, abs=1e-3)
    assert summary["final_ball_distance_m"] == pytest.approx(distance_m[-1])
    assert summary["mean_ball_distance_m"] == pytest.approx(distance_m.mean())
    assert summary["settling_time_s"] is not None and summary["settling_time_s"] <= 1.5
    assert summary["final_ball_distance_m"] < 0.005
    error_m = np.linalg.norm(estimate[:, 0:2] - truth[:, 0:2], axis=1)
    assert summary["ball_pos_rmse_m"] == pytest.approx(np.sqrt(np.mean(error_m**2)))
    assert summary["ball_pos_rmse_m"] < 0.002
    assert 0.0 < summary["max_abs_tilt_cmd_rad"] <= 0.1 + 1e-7  # float32 actions
    assert set(summary["versions"]) == set(VERSIONED_PACKAGES)


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
