"""A fourth system added from outside the package runs through every layer and command.

The toy of this folder (a camera above a point mass) is one module per layer plus a
``System`` record, registered by tests/conftest.py; nothing in the package names it. The
env suite (tests/envs/test_envs.py, test_copies.py) and the per-layer checks
(tests/train/core/test_systems.py) run on it with the package's systems; here it goes through
``run``, ``compare``, ``sweep`` and ``train`` as a user would call them.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import toy_system
from observer_gym.envs import SYSTEMS
from observer_gym.train.cli import main

ENV = ["--env", "PointMass-v0", "--no-progress"]


def test_the_toy_is_a_registered_system():
    assert toy_system.SYSTEM in SYSTEMS


@pytest.mark.parametrize("controller", ["pd", "lqr"])  # its own, and the package's generic
def test_run_settles_the_mass_on_the_kalman_filters_estimate(tmp_path, controller):
    out = tmp_path / "run"
    argv = ["run", *ENV, "--observer", "kf", "--controller", controller, "--episodes", "2"]
    assert main([*argv, "--steps", "60", "--out", str(out)]) == 0
    summary = json.loads((out / "results.json").read_text())["summary"]
    # PD with kp = kd = 4 is critically damped at 2 rad/s: from <= 0.15 m, (1 + 2t) e^-2t
    # leaves < 3 mm after 3 s (the LQR is faster); on the camera's estimate within 1 cm
    assert summary["final_distance_m"] < 0.01, summary
    assert summary["position_rmse_m"] < 0.005, summary  # 80 x 60 px, 12 mm per pixel


def test_compare_pairs_the_oracle_and_the_filter_on_the_same_starts(tmp_path):
    out = tmp_path / "compare"
    argv = ["compare", *ENV, "--observers", "oracle,kf-measurements", "--controllers", "pd"]
    assert main([*argv, "--episodes", "2", "--steps", "40", "--out", str(out)]) == 0
    results = json.loads((out / "results.json").read_text())
    assert [(p["observer"], p["controller"]) for p in results["pairs"]] == [
        ("oracle", "pd"),
        ("kf-measurements", "pd"),
    ]


def test_sweep_over_pixel_noise_keeps_the_world(tmp_path):
    out = tmp_path / "sweep"
    argv = ["sweep", *ENV, "--vary", "measurement_noise_px=0,2", "--observers", "kf-measurements"]
    assert (
        main([*argv, "--controllers", "pd", "--episodes", "2", "--steps", "30", "--out", str(out)])
        == 0
    )
    results = json.loads((out / "results.json").read_text())
    assert results["starts_match_across_grid"] is True
    assert len(results["cells"]) == 2


@pytest.mark.slow  # a real PPO training: 2.6 s (load ~2)
def test_train_then_run_the_agent(tmp_path):
    out = tmp_path / "agent"
    argv = ["train", *ENV, "--algo", "ppo", "--obs", "estimate", "--timesteps", "64"]
    assert (
        main(
            [
                *argv,
                "--hyperparam",
                "n_steps=32",
                "--hyperparam",
                "batch_size=16",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    config = json.loads((out / "config.json").read_text())
    assert config["env_id"] == "toy/PointMass-v0"
    assert config["hyperparams"]["vec_env"] == "dummy"  # from the toy task's HYPERPARAMS
    run_out = tmp_path / "run"
    argv = ["run", *ENV, "--observer", "kf", "--controller", f"ppo:{out}", "--episodes", "1"]
    assert main([*argv, "--steps", "10", "--out", str(run_out)]) == 0
    episodes = json.loads((run_out / "results.json").read_text())["episodes"]
    assert np.isfinite(episodes[0]["return"])
