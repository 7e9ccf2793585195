"""The agents shipped in the package: each loads by name (``ppo:<name>``), acts on its
fingerprint's observation as it did when shipped, says in its README how it was trained,
and stays small; and the mechanism on a freshly shipped agent."""

from __future__ import annotations

from pathlib import PurePosixPath

import pytest

from observer_gym.envs import system_for_id
from observer_gym.train.core.tasks import task_of
from observer_gym.train.experiments.episode import build_controller
from observer_gym.train.experiments.request import resolve_controller
from observer_gym.train.rl import shipped
from observer_gym.train.rl.agent import Agent
from observer_gym.train.rl.run_dir import model_files, parse_agent_spec, read_config
from observer_gym.train.rl.ship_agent import (
    fingerprint_difference,
    read_fingerprint,
    ship_agent,
    shipped_config,
)
from observer_gym.train.rl.training import train_agent

MAX_AGENT_BYTES = 500_000  # the package stays small: a few hundred kB per agent at most


@pytest.mark.parametrize("name", shipped.shipped_names())
def test_every_shipped_agent_acts_as_its_fingerprint_says(name):
    folder = shipped.shipped_path(name)
    config = read_config(folder)
    assert parse_agent_spec(f"{config['algo']}:{name}") == (config["algo"], folder)
    assert fingerprint_difference(folder) <= 1e-6
    agent = Agent.load(folder)
    assert agent.timesteps == model_files(folder)[2] > 0
    # <system>-<obs>, -<observer> for an estimate of another observer than the system's
    # default on measurements, -<features> for a feature set given with --hyperparam (not
    # the YAML's), and -randomized for an agent trained with --randomize
    overrides = dict(map(tuple, config.get("cli_args", {}).get("hyperparam") or []))
    default_observer = task_of(system_for_id(config["env_id"])).ESTIMATE_OBSERVERS["measurements"]
    reads_another = config["obs"] == "estimate" and config["observer"] != default_observer
    observer = f"-{config['observer']}" if reads_another else ""
    features = f"-{overrides['features']}" if "features" in overrides else ""
    randomized = "-randomized" if config.get("randomize") else ""
    system = system_for_id(config["env_id"]).name
    assert name == f"{system}-{config['obs']}{observer}{features}{randomized}"
    # where the run lived on the trainer's machine is not recorded (ship_agent)
    assert not PurePosixPath(config.get("cli_args", {}).get("out") or "runs").is_absolute()
    readme = (folder / shipped.README_FILE).read_text()
    assert "observer-gym train" in readme and f"--seed {config['seed']}" in readme
    # the README's command gives every hyperparameter the run overrode
    for key, value in overrides.items():
        assert f"--hyperparam {key}={value}" in readme, key
    # the README's command draws what the run drew: every key, with its range or choices
    for key, spec in (config.get("randomize") or {}).items():
        drawn = (
            "|".join(map(str, spec["choices"]))
            if "choices" in spec
            else (f"{spec['low']}:{spec['high']}")
        )
        assert f"--randomize {key}={drawn}" in readme.replace("'", ""), key
    assert sum(p.stat().st_size for p in folder.iterdir()) < MAX_AGENT_BYTES


@pytest.mark.slow  # trains and ships an agent: 2.2 s (load ~2)
def test_shipping_an_agent_makes_it_loadable_by_name(tmp_path, monkeypatch):
    run = tmp_path / "run"
    train_agent(
        "BallTable-v0", "ppo", "state", run, timesteps=128, n_envs=1, vec_env="dummy",
        hyperparams={"n_steps": 128, "batch_size": 64, "eval_freq": 10_000, "eval_episodes": 1},
        progress=False,
    )  # fmt: skip
    monkeypatch.setattr(shipped, "SHIPPED_DIR", tmp_path / "agents")
    readme = "trained by `observer-gym train ... --seed 0`\n"
    folder = ship_agent(run, "ball_table-state", readme, folder=tmp_path / "agents")
    assert shipped.shipped_names() == ("ball_table-state",)
    assert fingerprint_difference(folder) == 0.0
    assert read_fingerprint(folder).observation.shape == (8,)
    system = system_for_id("BallTable-v0")
    entry = resolve_controller(system, "ppo:ball_table-state")
    controller = build_controller(entry, None, system)
    assert controller.run_dir == str(folder) and controller.timesteps == 128
    # a folder of that name here wins over the shipped agent
    monkeypatch.chdir(tmp_path)
    (tmp_path / "ball_table-state").mkdir()
    assert parse_agent_spec("ppo:ball_table-state")[1].resolve() == tmp_path / "ball_table-state"
    with pytest.raises(ValueError, match="only a finished run"):
        ship_agent(tmp_path / "ball_table-state", "x", readme, folder=tmp_path / "agents")


def test_a_shipped_config_records_the_run_folder_relative():
    config = {"algo": "ppo", "cli_args": {"out": "/home/me/runs-rand/ppo-3", "seeds": [0, 1]}}
    assert shipped_config(config) == {
        "algo": "ppo",
        "cli_args": {"out": "runs/ppo-3", "seeds": [0, 1]},
    }
    assert shipped_config({"algo": "ppo"}) == {"algo": "ppo"}  # a run made by the library
