"""TargetFollower-v0 in ``observer-gym run`` (train/core/tasks/target_follower.py): the
observers and the VTC in closed loop, occlusions found and their recovery measured."""

from __future__ import annotations

import json

import numpy as np

from observer_gym.envs.target_follower import STATE_DIM, StateIndex
from observer_gym.train.core.tasks import target_follower as task
from observer_gym.train.experiments.run import run_experiment


def test_occlusion_intervals_are_found_in_the_ground_truth():
    state = np.zeros((10, STATE_DIM))
    state[:, StateIndex.TRACKING_VALID] = 1.0
    state[:, StateIndex.TARGET_VISIBLE] = [1, 0, 0, 1, 1, 0, 1, 1, 1, 0]
    state[5, StateIndex.X_I] = 500.0  # off the image: lost, not occluded
    assert task.occlusion_intervals(state, 160.0, 120.0) == [(1, 2), (9, 9)]


def test_run_with_an_occlusion_reports_its_recovery(tmp_path):
    results = run_experiment(
        env_id="TargetFollower-v0",
        observer="stkf-measurements",
        controller="vtc",
        episodes=2,
        seed=0,
        out_dir=tmp_path,
        steps=120,
        progress=False,
        env_kwargs={"target_motion": "profile"},
        reset_options={"occlusions_s": (3.0,)},
    )
    summary = results["summary"]
    print(f"\n{summary}")
    assert summary["occlusions"] == 2 and summary["fraction_recovered"] == 1.0
    assert 0.0 < summary["recovery_time_max_s"] < 5.0
    assert summary["fraction_in_image"] == 1.0
    assert 0.6 < summary["fraction_visible"] < 0.8  # hidden ~3.5 s of 12 s
    # predicted through the occlusion: valid from the second frame on (the track starts at
    # the first detection and is confirmed by the next), 120 of the 121 samples
    assert summary["fraction_estimate_valid"] == 120 / 121
    assert summary["centre_error_px"] < 20.0  # the start (up to ~40 px off) included
    for name in ("image.png", "error.png", "estimate.png", "results.json"):
        assert (tmp_path / name).stat().st_size > 0
    saved = json.loads((tmp_path / "results.json").read_text())
    assert saved["config"]["pipeline_options"] == {"filter": "stkf"}
