"""``observer-gym train`` / ``evaluate``: a small PPO run saves, loads and predicts
identically; resume keeps the timestep count; a killed run keeps its last checkpoint;
same seed, same model."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from stable_baselines3 import PPO

from observer_gym.envs import system_for_id
from observer_gym.train.cli import main
from observer_gym.train.core.observer_env import make_env, resolve_observer
from observer_gym.train.experiments.evaluate import evaluate_agent
from observer_gym.train.experiments.run import run_experiment
from observer_gym.train.rl.agent import Agent, model_files
from observer_gym.train.rl.checkpoints import latest_checkpoint
from observer_gym.train.rl.training import resume_training, train_agent

# Small budgets: rollouts of 2 envs x 256 steps, an evaluation episode every 1,000 steps.
SMALL = {"n_steps": 256, "batch_size": 64, "eval_freq": 1000, "eval_episodes": 1}


def _train(out_dir: Path, timesteps: int = 2000, seed: int = 0, **overrides) -> dict:
    return train_agent(
        "BallTable-v0",
        "ppo",
        "estimate",
        out_dir,
        timesteps=timesteps,
        seed=seed,
        n_envs=2,
        hyperparams={**SMALL, "checkpoint_freq": 1000, **overrides},
        progress=False,
    )


@pytest.fixture(scope="module")
def ppo_run(tmp_path_factory) -> Path:
    """A 2,000-step PPO run on BallTable from the observer's estimate (measurements), in
    two spawned SubprocVecEnv workers."""
    out_dir = tmp_path_factory.mktemp("ppo") / "run"
    state = _train(out_dir, vec_env="subproc")
    assert state["status"] == "finished"
    return out_dir


def _parameters(model) -> list[np.ndarray]:
    return [p.detach().cpu().numpy().copy() for p in model.policy.parameters()]


# ppo_run, a 2,000-step PPO run in two spawned workers (13 s idle), is slow with the three
# tests that read it; conftest.py's tiny_run is a training in the default run
@pytest.mark.slow
def test_run_writes_what_it_promises(ppo_run):
    config = json.loads((ppo_run / "config.json").read_text())
    state = json.loads((ppo_run / "state.json").read_text())
    assert config["observer"] == "kf-measurements" and config["obs"] == "estimate"
    assert config["hyperparams"]["n_steps"] == 256  # the override, resolved
    assert config["hyperparams"]["vec_env"] == "subproc"
    assert {"stable-baselines3", "torch", "gymnasium"} <= set(config["versions"])
    # PPO collects whole rollouts of n_envs x n_steps = 512 steps: 4 of them pass 2,000.
    assert state["timesteps"] == 2048 and state["status"] == "finished"
    for name in ("model.zip", "vecnormalize.npz", "final.json", "curve.png", "eval.csv"):
        assert (ppo_run / name).is_file(), name
    assert len(list((ppo_run / "monitor").glob("*.monitor.csv"))) == 2
    assert (ppo_run / "logs" / "start" / "progress.csv").stat().st_size > 0
    rows = np.genfromtxt(ppo_run / "eval.csv", delimiter=",", names=True)
    # every 1,000 steps (2 envs: the count moves by 2) and the final policy
    assert list(rows["timesteps"]) == [1000, 2000, 2048]
    assert np.all(rows["length_mean"] == 500)  # full BallTable episodes
    assert latest_checkpoint(ppo_run / "checkpoints")["timesteps"] == 2048


@pytest.mark.slow  # ppo_run; test_shipped.py loads an agent in the default run
def test_saved_agent_predicts_as_the_sb3_model_it_saved(ppo_run):
    """Agent.load (VecNormalize statistics + model + action map) against SB3's own
    loader and VecNormalize's formula on the saved arrays, on observations of the
    observer's env."""
    agent = Agent.load(ppo_run)
    model = PPO.load(ppo_run / "model.zip", device="cpu")
    with np.load(ppo_run / "vecnormalize.npz", allow_pickle=False) as stats:
        mean, var = stats["obs.mean"], stats["obs.var"]
        clip, epsilon = float(stats["clip_obs"]), float(stats["epsilon"])

    def normalize_obs(obs):
        return np.clip((obs - mean) / np.sqrt(var + epsilon), -clip, clip).astype(np.float32)

    checkpoint = Agent.load(ppo_run)  # a second load: same weights, same actions
    system = system_for_id("observer_gym/BallTable-v0")
    env = make_env(system, resolve_observer(system, "kf-measurements"))
    try:
        obs, _ = env.reset(seed=3)
        low, high = env.action_space.low, env.action_space.high
        for _ in range(20):
            action, _ = agent.predict(obs)
            raw, _ = model.predict(normalize_obs(obs), deterministic=True)
            expected = low + (np.clip(raw, -1, 1) + 1) / 2 * (high - low)
            np.testing.assert_allclose(action, expected, rtol=0, atol=1e-7)
            np.testing.assert_array_equal(checkpoint.predict(obs)[0], action)
            assert env.action_space.contains(action)
            obs, *_ = env.step(action)
    finally:
        env.close()
    for a, b in zip(_parameters(agent.model), _parameters(model), strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.slow  # ppo_run
def test_evaluate_scores_like_run(ppo_run, tmp_path):
    """evaluate = run with the agent as the controller: same results.json numbers."""
    evaluated = evaluate_agent(ppo_run, 2, tmp_path / "eval", seed=5, steps=60, progress=False)
    ran = run_experiment(
        "BallTable-v0",
        "kf-measurements",
        f"ppo:{ppo_run}",
        2,
        5,
        tmp_path / "run",
        steps=60,
        progress=False,
    )
    assert evaluated["episodes"] == ran["episodes"]
    assert evaluated["config"]["controller_config"]["timesteps"] == 2048
    # The agent reads any observer of the state layout, e.g. the true state:
    oracle = evaluate_agent(ppo_run, 1, tmp_path / "o", observer="oracle", steps=20, progress=False)
    assert oracle["config"]["observer"] == "oracle"
    with pytest.raises(ValueError, match="trained with --obs estimate"):
        evaluate_agent(ppo_run, 1, tmp_path / "p", observer="pixels", progress=False)


@pytest.mark.slow  # three PPO trainings (70 s at load 7)
def test_same_seed_same_model_on_cpu(tmp_path):
    """Two runs with seed 0 give identical weights and evaluation curves; seed 1 differs."""
    runs = {}
    for name, seed in (("a", 0), ("b", 0), ("c", 1)):
        _train(tmp_path / name, timesteps=1000, seed=seed, vec_env="dummy")
        runs[name] = PPO.load(tmp_path / name / "model.zip", device="cpu")
    curves = {
        name: np.genfromtxt(tmp_path / name / "eval.csv", delimiter=",", names=True)
        for name in runs
    }
    for a, b in zip(_parameters(runs["a"]), _parameters(runs["b"]), strict=True):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(curves["a"]["return_mean"], curves["b"]["return_mean"])
    assert any(
        not np.array_equal(a, c)
        for a, c in zip(_parameters(runs["a"]), _parameters(runs["c"]), strict=True)
    )
    assert torch.get_num_threads() == 1  # the YAML's torch_threads, set by the run


@pytest.mark.slow  # two trainings (24 s at load 7); test_killed_run_...[kill-1] resumes too
def test_resume_continues_the_timestep_count(tmp_path):
    out = tmp_path / "run"
    first = _train(out, timesteps=1000, vec_env="dummy")
    assert first["timesteps"] == 1024
    resumed = resume_training(out, timesteps=2000, progress=False)
    assert resumed["status"] == "finished"
    assert resumed["timesteps"] == 2048 and resumed["segment_steps"] == 1024
    assert PPO.load(out / "model.zip").num_timesteps == 2048
    rows = np.genfromtxt(out / "eval.csv", delimiter=",", names=True)
    assert list(rows["timesteps"]) == [1000, 1024, 2000, 2048]  # one curve, carried on
    assert (out / "logs" / "resume-1024" / "progress.csv").is_file()
    assert json.loads((out / "config.json").read_text())["hyperparams"]["n_timesteps"] == 2000


@pytest.mark.parametrize(
    ("how", "n_envs"),
    [  # SIGTERM to the trainer; SIGINT to it and its workers
        # a real PPO training in a subprocess (13 s idle); test_signal_in_write.py stops
        # a checkpoint write, test_kill_safe.py a killed run, in the default run
        pytest.param("kill", 1, marks=pytest.mark.slow),
        pytest.param("ctrl-c", 2, marks=pytest.mark.slow),  # 2 workers (62 s at load 7)
    ],
)
def test_killed_run_keeps_its_last_checkpoint_and_resumes(tmp_path, how, n_envs):
    """Stopped in the middle of training: exit code 130, the last checkpoint loads, and
    --resume carries on from its count."""
    out = tmp_path / "run"
    command = [
        sys.executable, "-m", "observer_gym.train.cli", "train", "--env", "BallTable-v0",
        "--algo", "ppo", "--obs", "state", "--timesteps", "200000", "--n-envs", str(n_envs),
        "--hyperparam", "n_steps=256", "--hyperparam", "checkpoint_freq=500",
        "--hyperparam", "eval_freq=100000", "--out", str(out), "--no-progress",
    ]  # fmt: skip
    process = subprocess.Popen(
        command,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        start_new_session=True,  # its own process group, as a terminal's foreground job
        # a shell's background job ignores SIGINT; a terminal's foreground job does not
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        deadline = time.monotonic() + 120
        while latest_checkpoint(out / "checkpoints") is None:
            assert process.poll() is None, process.stdout.read().decode()
            assert time.monotonic() < deadline, "no checkpoint within 120 s"
            time.sleep(0.2)
        time.sleep(1.0)
        if how == "kill":
            os.kill(process.pid, signal.SIGTERM)
        else:  # what Ctrl-C does: SIGINT to every process of the foreground group
            os.killpg(process.pid, signal.SIGINT)
        output, _ = process.communicate(timeout=60)
    finally:
        process.kill()
    assert process.returncode == 130, output.decode()
    state = json.loads((out / "state.json").read_text())
    assert state["status"] == "interrupted"
    saved = latest_checkpoint(out / "checkpoints")
    assert saved["timesteps"] == state["last_checkpoint_timesteps"] > 0
    assert PPO.load(saved["model"]).num_timesteps == saved["timesteps"]
    assert model_files(out)[2] == saved["timesteps"]  # evaluate would use it
    assert not list((out / "checkpoints").glob(".*tmp*"))
    target = saved["timesteps"] + 512
    assert main(["train", "--resume", str(out), "--timesteps", str(target), "--no-progress"]) == 0
    resumed = json.loads((out / "state.json").read_text())
    assert resumed["status"] == "finished"
    assert target <= resumed["timesteps"] < target + 256 * n_envs


def test_bad_arguments_raise_before_anything_is_written(tmp_path):
    with pytest.raises(ValueError, match="unknown hyperparameter"):
        _train(tmp_path / "a", learning_rat=1e-3)
    with pytest.raises(ValueError, match="unknown obs"):
        train_agent("BallTable-v0", "ppo", "pixels", tmp_path / "b")
    with pytest.raises(ValueError, match="unknown algo"):
        train_agent("BallTable-v0", "a2c", "state", tmp_path / "c")
    with pytest.raises(ValueError, match="n_envs must be an integer >= 1"):
        train_agent("BallTable-v0", "ppo", "state", tmp_path / "d", n_envs=0)
    with pytest.raises(ValueError, match="obs_mode"):
        train_agent("BallTable-v0", "ppo", "state", tmp_path / "e", env_kwargs={"obs_mode": "rgb"})
    assert not any((tmp_path / name).exists() for name in "abcde")
    with pytest.raises(SystemExit, match="drop --algo"):
        main(["train", "--resume", str(tmp_path), "--algo", "ppo"])
    with pytest.raises(ValueError, match="not an observer-gym training run"):
        Agent.load(tmp_path)
