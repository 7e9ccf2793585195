"""Issue 43, defect 5, beyond tests/train/core/test_hostile_entries.py's refusal: what does
travel with an agent (its reward weights; the shipped rgb agent's camera and its set point
in its own pixels) reaches every level; a gym.make option outside the config is refused."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from observer_gym.train.experiments.benchmark.run import check_agent_task, check_benchmark
from observer_gym.train.experiments.benchmark.suite import load_suite
from observer_gym.train.rl.run_dir import write_config

REPO = Path(__file__).resolve().parents[3]
AGENTS = REPO / "train" / "rl" / "agents"
ROOT = REPO / "docs" / "results" / "benchmark" / "v1"


def _agent_with(tmp_path: Path, **env_kwargs) -> str:
    """A copy of the shipped BallCatcher agent whose config (hash rewritten) records
    ``env_kwargs`` as what it was trained with."""
    run_dir = tmp_path / "agent"
    shutil.copytree(AGENTS / "ball_catcher-estimate", run_dir)
    config = json.loads((run_dir / "config.json").read_text())
    config["env_kwargs"] = {**config.get("env_kwargs", {}), **env_kwargs}
    write_config(run_dir, config)
    return f"ppo:{run_dir}"


def test_a_gym_make_option_outside_the_config_is_refused(tmp_path):
    agent = _agent_with(tmp_path, max_episode_steps=10_000)
    with pytest.raises(ValueError, match=r"change the task: max_episode_steps=10000"):
        check_benchmark("BallCatcher-v1", "kf-measurements", agent, episodes=1)


def test_reward_weights_travel_to_every_level(tmp_path):
    agent = _agent_with(tmp_path, shaping_weight=2.0)
    request = check_benchmark("BallCatcher-v1", "kf-measurements", agent, episodes=1)
    assert request.agent_env_options == {"shaping_weight": 2.0}
    for level in request.suite.levels:
        assert dict(request.specs(level)[0].env_kwargs)["shaping_weight"] == 2.0


def test_the_shipped_rgb_agents_set_point_in_its_own_pixels_is_the_suites_task():
    """ppo:target_follower-rgb's desired_width_px (9.1875) is the default 35 px in its
    84 x 63 camera's pixels: accepted; the same number in the default camera's pixels is
    another task for that camera: refused."""
    request = check_benchmark("TargetFollower-v0", "pixels", "ppo:target_follower-rgb", 1)
    options = request.agent_env_options
    assert options["desired_width_px"] == pytest.approx(35.0 * request.camera_scale)
    suite = load_suite("observer_gym/TargetFollower-v0")
    with pytest.raises(ValueError, match=r"change the task: desired_width_px=35\.0"):
        check_agent_task(
            suite, "ppo:x", {**options, "desired_width_px": 35.0}, request.camera_scale
        )
