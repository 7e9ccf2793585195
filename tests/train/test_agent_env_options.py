"""A trained agent's env options travel with it: the episodes of its pairs in `run`,
`compare` and `sweep` are made with its config's env_kwargs (the shipped rgb agent's
84 x 84 image), under the command's own options, and results record them; other
controllers' episodes keep the command's options."""

from __future__ import annotations

import json

from observer_gym.train.cli import main
from observer_gym.train.experiments.request import resolve_request

ENV = "BallTable-v0"
RGB_AGENT = "ppo:ball_table-rgb"  # trained at image_width_px = image_height_px = 84
AGENT_OPTIONS = {"image_width_px": 84, "image_height_px": 84}


def test_an_agents_pairs_get_its_env_options_and_the_commands_win():
    request = resolve_request(ENV, ["pixels"], [RGB_AGENT], [0])
    agent = request.controller(RGB_AGENT)
    assert agent.kind == "agent" and agent.env_options == AGENT_OPTIONS
    assert request.env_kwargs_for(agent) == AGENT_OPTIONS
    assert request.agent_env_options == {RGB_AGENT: AGENT_OPTIONS}
    given = resolve_request(ENV, ["pixels"], [RGB_AGENT], [0], env_kwargs={"image_width_px": 96})
    assert given.env_kwargs_for(given.controller(RGB_AGENT)) == {
        "image_width_px": 96,
        "image_height_px": 84,
    }
    classical = resolve_request(ENV, ["kf-measurements"], ["lqr"], [0])
    assert classical.controller("lqr").env_options == {}
    assert classical.agent_env_options == {}


def test_compare_runs_the_rgb_agent_at_its_image_size_with_no_env_option(tmp_path):
    out = tmp_path / "cmp"
    argv = ["compare", "--env", ENV, "--observers", "pixels", "--controllers", RGB_AGENT,
            "--episodes", "1", "--steps", "5", "--workers", "1", "--no-progress",
            "--out", str(out)]  # fmt: skip
    assert main(argv) == 0
    config = json.loads((out / "results.json").read_text())["config"]
    assert config["agent_env_options"] == {RGB_AGENT: AGENT_OPTIONS}
    assert config["env_kwargs"] == {}


def test_run_records_the_options_its_env_was_made_with(tmp_path):
    out = tmp_path / "run"
    argv = ["run", "--env", ENV, "--observer", "pixels", "--controller", RGB_AGENT,
            "--episodes", "1", "--steps", "5", "--no-progress", "--out", str(out)]  # fmt: skip
    assert main(argv) == 0
    env_kwargs = json.loads((out / "results.json").read_text())["config"]["env_kwargs"]
    assert {k: env_kwargs[k] for k in AGENT_OPTIONS} == AGENT_OPTIONS
