"""The RL Baselines3 Zoo files shipped in the package: generated from our YAML (so they
cannot drift), Zoo's env through our wrapper is the env ``observer-gym train`` gives the
agent, and Zoo trains every system from them."""

from __future__ import annotations

import os
import shlex
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml

from observer_gym.envs.registration import PACKAGE_SYSTEMS as SYSTEMS  # those with zoo files
from observer_gym.train.rl import zoo
from observer_gym.train.rl.agent_env import OBS_TYPES, make_agent_env
from observer_gym.train.rl.hyperparams import ALGOS, algorithm_parameters, resolve_hyperparams

# Zoo's own keys (taken out of an entry before the rest goes to the algorithm)
ZOO_KEYS = {"n_timesteps", "n_envs", "policy", "env_kwargs", "env_wrapper", "normalize"}
ZOO_NOISE = {"noise_type", "noise_std"}


def test_the_shipped_files_are_what_our_yaml_generates():
    expected = {entry.name: zoo.zoo_text(entry) for entry in zoo.zoo_files()}
    shipped = {path.name: path.read_text() for path in zoo.ZOO_DIR.glob("*.yml")}
    assert sorted(shipped) == sorted(expected), "run 'python -m observer_gym.train.rl.zoo write'"
    stale = [name for name in expected if shipped[name] != expected[name]]
    assert not stale, f"stale Zoo files {stale}: run 'python -m observer_gym.train.rl.zoo write'"
    assert len(expected) == len(ALGOS) * len(SYSTEMS) * len(OBS_TYPES)


@pytest.mark.parametrize("algo", ALGOS)
def test_each_entry_carries_our_values(algo):
    """Every algorithm key of our resolved YAML is in the Zoo entry unchanged, and every
    Zoo key is Zoo's own or the algorithm's."""
    allowed = set(algorithm_parameters(algo)) | ZOO_KEYS | ZOO_NOISE
    for system in SYSTEMS:
        for obs in OBS_TYPES:
            path = zoo.zoo_path(algo, system.short_id, obs)
            (entry,) = yaml.safe_load(path.read_text()).values()
            ours = resolve_hyperparams(system.env_id, algo, obs)
            assert set(entry) <= allowed, (path.name, set(entry) - allowed)
            for key in set(entry) - ZOO_KEYS - ZOO_NOISE:
                assert entry[key] == ours[key], (path.name, key)
            assert entry["n_timesteps"] == ours["n_timesteps"]
            assert (
                entry["env_kwargs"]
                == {"obs_mode": entry["env_kwargs"]["obs_mode"]} | (ours["env_kwargs"])
            )
            if "action_noise" in ours:
                assert entry["noise_std"] == ours["action_noise"]["sigma"]


def test_the_wrapper_refuses_an_env_in_another_obs_mode(make_env):
    env = make_env("observer_gym/BallTable-v0", obs_mode="state")
    with pytest.raises(ValueError, match=r"set env_kwargs\.obs_mode: measurements"):
        zoo.agent_wrapper(env, "estimate")


def _zoo_env(path):
    """The env Zoo makes from the file at ``path`` (rl_zoo3's own wrapper reader)."""
    from rl_zoo3.utils import get_wrapper_class
    from stable_baselines3.common.monitor import Monitor

    ((env_id, entry),) = yaml.safe_load(path.read_text()).items()
    env = Monitor(gym.make(env_id, **entry["env_kwargs"]))
    return get_wrapper_class(entry)(env)


def _same_observations(a, b) -> None:
    if isinstance(a, dict):
        assert a.keys() == b.keys()
        for key in a:
            np.testing.assert_array_equal(a[key], b[key])
    else:
        np.testing.assert_array_equal(a, b)


@pytest.mark.slow
@pytest.mark.parametrize("system", SYSTEMS, ids=lambda s: s.name)
@pytest.mark.parametrize("obs", OBS_TYPES)
def test_zoo_makes_the_env_observer_gym_train_makes(system, obs):
    """Same spaces, observations and rewards for the same seed and actions."""
    pytest.importorskip("rl_zoo3")
    ours_params = resolve_hyperparams(system.env_id, "ppo", obs)
    theirs = _zoo_env(zoo.zoo_path("ppo", system.short_id, obs))
    ours = make_agent_env(
        system.env_id,
        obs,
        env_kwargs=ours_params["env_kwargs"],
        image=ours_params["image"],
        features=ours_params["features"],
    )
    try:
        assert theirs.observation_space == ours.observation_space
        assert theirs.action_space == ours.action_space
        _same_observations(theirs.reset(seed=3)[0], ours.reset(seed=3)[0])
        rng = np.random.default_rng(0)
        for _ in range(5):
            action = rng.uniform(-1, 1, ours.action_space.shape).astype(np.float32)
            step_theirs, step_ours = theirs.step(action), ours.step(action)
            _same_observations(step_theirs[0], step_ours[0])
            assert step_theirs[1] == step_ours[1]
    finally:
        theirs.close()
        ours.close()


@pytest.mark.slow
@pytest.mark.parametrize("system", SYSTEMS, ids=lambda s: s.name)
def test_zoo_trains_every_system_from_the_shipped_file(system, tmp_path):
    """A few hundred steps of ``python -m rl_zoo3.train`` with the shipped PPO file of the
    estimate (our VisionObserver wrapper in Zoo's envs); a smaller rollout so it is quick."""
    pytest.importorskip("rl_zoo3")
    command = [
        sys.executable, "-m", "rl_zoo3.train", "--algo", "ppo", "--env", system.env_id,
        "--gym-packages", "observer_gym.envs",
        "-conf", str(zoo.zoo_path("ppo", system.env_id, "estimate")),
        "-n", "256", "--eval-freq", "-1", "--vec-env", "dummy", "--seed", "0",
        "--log-folder", str(tmp_path), "-params", "n_envs:1", "n_steps:128", "batch_size:64",
    ]  # fmt: skip
    result = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-3000:]
    assert list(tmp_path.glob(f"ppo/*/{system.env_id.replace('/', '-')}.zip"))


def _documented_command(text: str) -> str:
    """The one ``python -m rl_zoo3.train`` command of a Markdown page, joined into one line."""
    (block,) = [
        line
        for line in text.replace("\\\n    ", "").splitlines()
        if line.startswith("python -m rl_zoo3.train")
    ]
    return block


def test_the_documented_command_is_the_one_a_file_prints():
    """docs/training.md shows the command in ppo_ball_table_estimate.yml's header, and every
    header's command gives Zoo's evaluation env the file's env_kwargs."""
    docs = Path(__file__).resolve().parents[3] / "docs" / "training.md"
    entry = zoo.zoo_hyperparams("observer_gym/BallTable-v0", "ppo", "estimate")
    assert _documented_command(docs.read_text()) == zoo.zoo_command(entry)
    for entry in zoo.zoo_files():
        words = shlex.split(zoo.zoo_command(entry, conf="x.yml"))
        given = words[words.index("--eval-env-kwargs") + 1 :]
        kwargs = {word.split(":", 1)[0]: eval(word.split(":", 1)[1]) for word in given}
        assert kwargs == entry.hyperparams["env_kwargs"], entry.name


@pytest.mark.slow
def test_the_documented_zoo_command_runs_with_evaluation(tmp_path):
    """The command of the shipped file's header, as printed (the shell finds the file), with a
    tiny budget appended: Zoo's evaluation env is the agent's, so the evaluations run."""
    pytest.importorskip("rl_zoo3")
    path = zoo.zoo_path("ppo", "BallTable-v0", "estimate")
    (printed,) = [
        line.removeprefix("#   ")
        for line in path.read_text().splitlines()
        if line.startswith("#   python -m rl_zoo3.train")
    ]
    budget = (
        "-n 256 --eval-freq 128 --eval-episodes 1 --save-freq -1 --vec-env dummy --seed 0 "
        f"--log-folder {shlex.quote(str(tmp_path))} -params n_envs:1 n_steps:128 batch_size:64"
    )
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}")
    result = subprocess.run(
        ["bash", "-c", f"{printed} {budget}"],
        capture_output=True, text=True, timeout=900, env=env,
    )  # fmt: skip
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-3000:]
    (evaluations,) = tmp_path.glob("ppo/*/evaluations.npz")
    assert len(np.load(evaluations)["timesteps"]) == 2
