"""A trained agent's env options travel with it: the episodes of its pairs in `run`,
`compare` and `sweep` are made with its config's env_kwargs (the shipped BallTable rgb
agent's 84 x 84 image, the TargetFollower one's 84 x 63 camera), under the command's own
options, and results record them; other controllers' episodes keep the command's
options."""

from __future__ import annotations

import json

import pytest

from observer_gym.envs import system_for_id
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


def test_the_target_follower_rgb_agent_runs_on_its_small_camera_with_no_env_option(tmp_path):
    """The shipped TargetFollower rgb agent was trained on an 84 x 63 camera with the focal
    lengths and the width set point scaled to it (ppo.yml's rgb env_kwargs); loading it by
    name brings those options to its episodes, whose frames are then that size and whose
    image state is in that camera's pixels, and the request's own options still win."""
    from observer_gym.train.core.observer_env import make_env, resolve_observer
    from observer_gym.train.rl.hyperparams import resolve_hyperparams

    env_id, agent_name = "observer_gym/TargetFollower-v0", "ppo:target_follower-rgb"
    options = resolve_hyperparams(env_id, "ppo", "rgb")["env_kwargs"]
    assert options["image_width_px"] == 84 and options["image_height_px"] == 63
    request = resolve_request("TargetFollower-v0", ["pixels"], [agent_name], [0])
    assert request.controller(agent_name).env_options == options
    assert request.env_kwargs_for(request.controller(agent_name)) == options
    system = system_for_id(env_id)
    env = make_env(
        system,
        resolve_observer(system, "pixels"),
        request.env_kwargs_for(request.controller(agent_name)),
    )
    try:
        frame, info = env.reset(seed=0)
        assert frame.shape == (63, 84, 3)
        # a target 1.1-1.7 m away is 7-11 px wide at this camera (26-43 px at 320 x 240)
        assert 6.0 < info["state"][2] < 12.0
    finally:
        env.close()
    given = resolve_request(
        "TargetFollower-v0", ["pixels"], [agent_name], [0], env_kwargs={"desired_width_px": 9.0}
    )
    # a pixel-valued option of the command is in the default camera's pixels: the agent's
    # episodes get it times its camera's scale, 84 / 320 (the same angle)
    scaled = given.env_kwargs_for(given.controller(agent_name))["desired_width_px"]
    assert scaled == pytest.approx(9.0 * 84 / 320, rel=1e-9)
    out = tmp_path / "run"
    argv = ["run", "--env", "TargetFollower-v0", "--observer", "pixels", "--controller",
            agent_name, "--episodes", "1", "--steps", "5", "--no-progress", "--out",
            str(out)]  # fmt: skip
    assert main(argv) == 0
    env_kwargs = json.loads((out / "results.json").read_text())["config"]["env_kwargs"]
    assert {k: env_kwargs[k] for k in options} == options
