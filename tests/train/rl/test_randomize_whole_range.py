"""``train --randomize``: the up-front check covers every value a draw can take, not
only the ranges' ends, so no draw part-way through training can build a world the env
refuses (a control period that is no whole multiple of the physics step, a shortest
flight above the longest, a launch under the floor)."""

from __future__ import annotations

import numpy as np
import pytest

from observer_gym.envs.ball_catcher import BallCatcherConfig
from observer_gym.train.cli import main
from observer_gym.train.rl.agent_env import make_agent_env
from observer_gym.train.rl.randomize import (
    check_randomize,
    check_spaces,
    draw_options,
    integer_options,
)
from observer_gym.train.rl.run_dir import read_config, write_config
from observer_gym.train.rl.training import train_agent

ENV = "observer_gym/BallCatcher-v1"


def check(randomize, env_kwargs=None):
    return check_randomize(ENV, "state", env_kwargs or {}, randomize)


def test_a_range_of_the_control_period_is_refused_though_its_ends_pass():
    randomize = {"control_dt_s": {"low": 0.01, "high": 0.05}}
    for end in (0.01, 0.05):
        BallCatcherConfig(control_dt_s=end)  # both ends build
    with pytest.raises(ValueError, match="whole multiple of physics_dt_s") as refused:
        BallCatcherConfig(control_dt_s=0.0326)  # a draw between them does not
    with pytest.raises(ValueError, match=r"randomize control_dt_s") as refused:
        check(randomize)
    message = str(refused.value)
    assert "choices" in message and "control_dt_s=A|B" in message
    with pytest.raises(ValueError, match=r"randomize physics_dt_s"):
        check({"physics_dt_s": {"low": 0.0005, "high": 0.001}})
    # as choices, each of them a whole multiple: taken, and every draw builds
    taken = check({"control_dt_s": {"choices": [0.01, 0.02, 0.05]}})
    rng = np.random.default_rng(0)
    for _ in range(50):
        BallCatcherConfig(**draw_options(taken, rng))
    # a range of width zero draws one value
    check({"control_dt_s": {"low": 0.02, "high": 0.02}})


def test_overlapping_flight_time_ranges_are_refused_though_their_ends_pass_together():
    randomize = {
        "flight_time_min_s": {"low": 0.3, "high": 0.5},
        "flight_time_max_s": {"low": 0.45, "high": 0.6},
    }
    # every LOW together and every HIGH together build; a draw of 0.49 and 0.46 does not
    BallCatcherConfig(flight_time_min_s=0.3, flight_time_max_s=0.45)
    BallCatcherConfig(flight_time_min_s=0.5, flight_time_max_s=0.6)
    with pytest.raises(ValueError, match=r"flight_time_min_s=0\.5.*flight_time_max_s=0\.45"):
        check(randomize)


def test_a_launch_range_that_reaches_under_the_floor_is_refused():
    randomize = {
        "launch_height_m": {"low": 0.3, "high": 1.0},
        "launch_spread_m": {"low": 0.1, "high": 0.3},
    }
    with pytest.raises(ValueError, match=r"launch_height_m=0\.3.*launch_spread_m=0\.3"):
        check(randomize)
    # with a fixed option beside it
    with pytest.raises(ValueError, match="launch_spread_m"):
        check({"launch_height_m": {"low": 0.3, "high": 1.0}}, {"launch_spread_m": 0.2})


def test_every_draw_of_a_checked_randomisation_builds():
    randomize = check(
        {
            "flight_time_min_s": {"low": 0.3, "high": 0.45},
            "flight_time_max_s": {"low": 0.45, "high": 0.6},
            "launch_height_m": {"low": 0.5, "high": 1.0},
            "launch_spread_m": {"low": 0.0, "high": 0.3},
            "frame_rate_hz": {"low": 20.0, "high": 100.0},
            "frame_phase_s": {"low": 0.0, "high": 0.009},
            "num_cameras": {"low": 1, "high": 2},
            "camera_preset": {"choices": ["alternating", "synchronised"]},
        }
    )
    rng = np.random.default_rng(1)
    integers = integer_options(ENV)
    for _ in range(2000):
        BallCatcherConfig(obs_mode="state", **draw_options(randomize, rng, integers))


def test_the_command_refuses_a_range_with_one_line(capsys, tmp_path):
    code = main(
        [
            "train", "--env", "BallCatcher-v1", "--algo", "ppo", "--obs", "state",
            "--randomize", "control_dt_s=0.01:0.05", "--timesteps", "256",
            "--out", str(tmp_path / "run"), "--no-progress",
        ]
    )  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert "control_dt_s" in err[0] and "choices" in err[0]
    assert not (tmp_path / "run").exists()


@pytest.mark.slow
def test_resume_of_a_run_recorded_with_an_unsafe_range_is_refused_up_front(tmp_path, capsys):
    # a run whose config.json recorded a control_dt_s range (as the check let through
    # before it covered the whole range): resume refuses it in one line, writing nothing
    out = tmp_path / "run"
    state = train_agent(
        ENV,
        "ppo",
        "state",
        out,
        timesteps=128,
        seed=0,
        n_envs=1,
        vec_env="dummy",
        randomize={"control_dt_s": {"choices": [0.01, 0.02]}},
        hyperparams={"n_steps": 64, "batch_size": 64, "eval_freq": 128, "checkpoint_freq": 64},
        progress=False,
    )
    assert state["status"] == "finished"
    config = read_config(out)
    config["randomize"] = {"control_dt_s": {"low": 0.01, "high": 0.05}}
    write_config(out, config)
    before = {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()}
    capsys.readouterr()
    assert main(["train", "--resume", str(out), "--timesteps", "256", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "control_dt_s" in err[0] and "choices" in err[0], err
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()} == before


def test_a_randomisation_that_changes_the_agents_spaces_is_refused_before_training(
    capsys, tmp_path
):
    # one camera or two: two images or one for a pixel agent; the check of the options
    # alone takes it, the first draw of the other count stopped training
    check_randomize(ENV, "rgb", {}, {"num_cameras": {"low": 1, "high": 2}})
    code = main(
        [
            "train", "--env", "BallCatcher-v1", "--algo", "ppo", "--obs", "rgb",
            "--env-option", "image_width_px=64", "--env-option", "image_height_px=48",
            "--randomize", "num_cameras=1:2", "--timesteps", "256",
            "--out", str(tmp_path / "run"), "--no-progress",
        ]
    )  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert "num_cameras=2 changes the agent's spaces" in err[0]
    assert not (tmp_path / "run").exists()
    # options that keep the spaces pass: the estimate has the state's layout
    checked = check_randomize(ENV, "measurements", {}, {"num_cameras": {"low": 1, "high": 2}})
    check_spaces(lambda drawn: make_agent_env(ENV, "estimate", "measurements", drawn), checked)
