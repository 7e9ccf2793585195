"""``observer-gym train --seeds``: one ordinary run per seed, trained in parallel worker
processes with the weights of sequential single-seed runs; the aggregate (learning curves
with a band, IQM with an interval, rliable's method); evaluate and compare taking the
multi-seed folder as one agent; resume of unfinished seeds; a killed run."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from stable_baselines3 import PPO

from observer_gym.train.cli import main
from observer_gym.train.core.tasks import ball_table
from observer_gym.train.experiments.compare import run_comparison
from observer_gym.train.experiments.evaluate import evaluate_agent, evaluate_seeds
from observer_gym.train.reports import aggregate, compare_report
from observer_gym.train.rl.agent import Agent
from observer_gym.train.rl.checkpoints import latest_checkpoint
from observer_gym.train.rl.run_dir import expand_agent, is_multi_seed, read_config
from observer_gym.train.rl.seeds import SeedsConfig, resume_seeds, train_seeds
from observer_gym.train.rl.training import train_agent

SEEDS = (0, 1, 2)
STEPS = 512
REPS = 200  # bootstrap replications: enough to test, quick
# rollouts of 128 steps in one in-process env, episodes of at most 100 steps; evaluation
# (1 episode) and checkpoints at 256 and 512 steps
OPTIONS = {
    "timesteps": STEPS,
    "n_envs": 1,
    "vec_env": "dummy",
    "env_kwargs": {"max_episode_steps": 100},
    "hyperparams": {
        "n_steps": 128,
        "batch_size": 64,
        "eval_freq": 256,
        "eval_episodes": 1,
        "checkpoint_freq": 256,
    },
}


@pytest.fixture(scope="module")
def seeds_run(tmp_path_factory) -> Path:
    """Three seeds of PPO on BallTable's state, 512 steps each, in three processes."""
    out = tmp_path_factory.mktemp("seeds") / "out"
    result = train_seeds(
        "BallTable-v0", "ppo", "state", out, SEEDS, workers=3, progress=False, reps=REPS, **OPTIONS
    )
    assert result.status == "finished"
    assert [run.seed for run in result.runs] == list(SEEDS)
    assert result.steps_trained == 3 * STEPS
    return out


def _parameters(path: Path) -> list[np.ndarray]:
    model = PPO.load(path, device="cpu")
    return [p.detach().numpy().copy() for p in model.policy.parameters()]


@pytest.mark.slow  # a multi-seed training and single runs (34 s at load 7)
def test_each_seed_is_an_ordinary_run(seeds_run):
    assert is_multi_seed(seeds_run)
    record = SeedsConfig.read(seeds_run)
    assert record.seeds == SEEDS and record.target_timesteps == STEPS
    for seed in SEEDS:
        run = seeds_run / f"seed_{seed}"
        config = read_config(run)
        assert config["seed"] == seed and config["obs"] == "state"
        assert json.loads((run / "state.json").read_text())["status"] == "finished"
        assert Agent.load(run).timesteps == STEPS
    assert expand_agent(f"ppo:{seeds_run}") == [f"ppo:{seeds_run / f'seed_{s}'}" for s in SEEDS]
    with pytest.raises(ValueError, match="holds a multi-seed run"):
        read_config(seeds_run)  # what 'run --controller ppo:OUT' says


@pytest.mark.slow  # on the multi-seed training (31 s to build at load 4)
def test_the_aggregate_has_curves_with_a_band_and_the_iqm(seeds_run):
    for name in ("learning_curves.png", "aggregate.json", "aggregate.md"):
        assert (seeds_run / name).stat().st_size > 0, name
    data = json.loads((seeds_run / "aggregate.json").read_text())
    curve = data["curve"]
    assert curve["timesteps"] == [256, 512]
    for low, mean, high in zip(curve["low"], curve["mean"], curve["high"], strict=True):
        assert low <= mean <= high
    finals = [
        np.genfromtxt(seeds_run / f"seed_{s}" / "eval.csv", delimiter=",", names=True)[
            "return_mean"
        ][-1]
        for s in SEEDS
    ]
    final = data["final_return"]
    np.testing.assert_allclose(final["scores"], finals)
    np.testing.assert_allclose(curve["mean"][-1], np.mean(finals))
    assert final["iqm"] == pytest.approx(np.mean(finals))  # 3 seeds: nothing trimmed
    assert min(finals) <= final["iqm_low"] <= final["iqm"] <= final["iqm_high"] <= max(finals)
    assert final["reps"] == REPS and "rliable" in final["method"]
    assert "IQM" in (seeds_run / "aggregate.md").read_text()


@pytest.mark.slow  # on the multi-seed training (31 s to build at load 4)
def test_parallel_seeds_equal_a_sequential_single_seed_run(seeds_run, tmp_path):
    """Seed 1 trained alone, in this process, after other training: the same weights and
    evaluation curve as in its worker process beside two other seeds."""
    train_agent(
        "BallTable-v0", "ppo", "state", tmp_path / "alone", seed=1, progress=False, **OPTIONS
    )
    together = seeds_run / "seed_1"
    for a, b in zip(
        _parameters(tmp_path / "alone" / "model.zip"),
        _parameters(together / "model.zip"),
        strict=True,
    ):
        np.testing.assert_array_equal(a, b)
    curves = [
        np.genfromtxt(p / "eval.csv", delimiter=",", names=True)
        for p in (tmp_path / "alone", together)
    ]
    np.testing.assert_array_equal(curves[0]["return_mean"], curves[1]["return_mean"])


@pytest.fixture
def no_plots(monkeypatch):
    """Skip drawing (most of a short evaluation's time)."""
    monkeypatch.setattr(compare_report, "plot_bars", lambda *args, **kwargs: None)
    monkeypatch.setattr(ball_table, "plot", lambda records, observer, out_dir: [])


@pytest.mark.slow  # on the multi-seed training (31 s to build at load 4)
def test_evaluate_and_compare_score_every_seed_on_the_same_episodes(seeds_run, tmp_path, no_plots):
    evaluation = evaluate_seeds(
        seeds_run, 2, tmp_path / "eval", steps=30, progress=False, reps=REPS
    )
    assert set(evaluation.per_seed) == set(SEEDS) and evaluation.metric == "mean_distance_m"
    alone = evaluate_agent(seeds_run / "seed_2", 2, tmp_path / "one", steps=30, progress=False)
    assert evaluation.results[2]["episodes"] == alone["episodes"]
    assert evaluation.per_seed[2] == pytest.approx(
        np.mean([e["mean_distance_m"] for e in alone["episodes"]])
    )
    stats = evaluation.statistics
    assert stats.mean == pytest.approx(np.mean(list(evaluation.per_seed.values())))
    assert stats.iqm_low <= stats.iqm <= stats.iqm_high
    written = json.loads((tmp_path / "eval" / "across_seeds.json").read_text())
    assert written["statistics"]["scores"] == list(stats.scores)
    assert (tmp_path / "eval" / "seed_0" / "results.json").is_file()

    compared = run_comparison(
        "BallTable-v0",
        ["oracle"],
        ["lqr", f"ppo:{seeds_run}"],
        [0, 1],
        tmp_path / "compare",
        steps=30,
        progress=False,
    )
    assert len(compared["pairs"]) == 4  # lqr and one agent per seed
    (entry,) = compared["across_seeds"]
    assert entry["controller"] == f"ppo:{seeds_run}"
    assert entry["per_seed"] == {str(s): pytest.approx(v) for s, v in evaluation.per_seed.items()}
    assert "Multi-seed agents" in (tmp_path / "compare" / "table.md").read_text()


@pytest.mark.slow  # a killed and resumed multi-seed training (30 s at load 7)
def test_resume_trains_only_the_unfinished_seeds(seeds_run, tmp_path):
    """Seed 1 made 'interrupted' at its 256-step checkpoint, seed 2 'killed' before its
    first: resume trains seed 1 on from 256 steps and seed 2 from the start, leaves seed 0
    alone, and aggregates again."""
    out = tmp_path / "out"
    shutil.copytree(seeds_run, out)
    for file in ("model.zip", "vecnormalize.npz", "final.json", "aggregate.json"):
        for path in [out / "seed_1" / file, out / "seed_2" / file, out / file]:
            path.unlink(missing_ok=True)
    checkpoints = out / "seed_1" / "checkpoints"
    # latest.json as it stood after the checkpoint at 256 steps (the set's own record)
    shutil.copyfile(checkpoints / "checkpoint_256.json", checkpoints / "latest.json")
    state = json.loads((out / "seed_1" / "state.json").read_text())
    (out / "seed_1" / "state.json").write_text(
        json.dumps({**state, "status": "interrupted", "timesteps": 256})
    )
    shutil.rmtree(out / "seed_2" / "checkpoints")
    state = json.loads((out / "seed_2" / "state.json").read_text())
    dead_writer = {**state["writer"], "pid": 2**22 + 7}  # no such process
    (out / "seed_2" / "state.json").write_text(
        json.dumps({**state, "status": "running", "writer": dead_writer})
    )
    untouched = (out / "seed_0" / "model.zip").stat().st_mtime_ns

    with pytest.warns(UserWarning) as warned:
        result = resume_seeds(out, workers=2, progress=False, reps=REPS)
    assert any("seed 2" in str(w.message) and "killed" in str(w.message) for w in warned)
    assert result.status == "finished"
    assert result.steps_trained == (STEPS - 256) + STEPS
    assert (out / "seed_0" / "model.zip").stat().st_mtime_ns == untouched
    assert (out / "aggregate.json").is_file()
    rows = np.genfromtxt(out / "seed_1" / "eval.csv", delimiter=",", names=True)
    assert list(rows["timesteps"]) == [256, 512, 512]  # the curve carried on
    # seed 2, from its start again, is the run it was
    for a, b in zip(
        _parameters(out / "seed_2" / "model.zip"),
        _parameters(seeds_run / "seed_2" / "model.zip"),
        strict=True,
    ):
        np.testing.assert_array_equal(a, b)


def test_bad_requests_raise_before_anything_is_written(tmp_path):
    def train(**kwargs):
        arguments = {"workers": 1, "progress": False, **OPTIONS, **kwargs}
        return train_seeds("BallTable-v0", "ppo", "state", tmp_path / "out", **arguments)

    for seeds, message in (([], "at least one"), ([0, 0], "distinct"), ([-1], ">= 0")):
        with pytest.raises(ValueError, match=message):
            train(seeds=seeds)
    with pytest.raises(ValueError, match="workers applies to the local backend only"):
        train(seeds=[0], backend="ray", workers=2)
    with pytest.raises(ValueError, match="unknown hyperparameter"):
        train(seeds=[0], hyperparams={"learning_rat": 1e-3})
    assert not (tmp_path / "out").exists()


def test_across_seeds_is_rliable_iqm_with_its_bootstrap_interval():
    from scipy import stats

    scores = {seed: float(value) for seed, value in enumerate([1, 2, 3, 4, 5, 6, 7, 100])}
    result = aggregate.across_seeds(scores, reps=REPS)
    assert result.iqm == pytest.approx(stats.trim_mean(list(scores.values()), 0.25))
    assert result.iqm_low < result.iqm < result.iqm_high
    assert aggregate.across_seeds(scores, reps=REPS) == result  # a seeded bootstrap
    with pytest.raises(ValueError, match="at least one"):
        aggregate.across_seeds({})
    with pytest.raises(ValueError, match="finite"):
        aggregate.across_seeds({0: float("nan")})


def test_scores_across_seeds_need_no_rliable(monkeypatch):
    """The statistics are NumPy's and SciPy's (reports/bootstrap.py): with rliable
    unimportable the same numbers come out."""
    scores = {seed: float(value) for seed, value in enumerate([3, 1, 4, 1, 5, 9, 2, 6])}
    before = aggregate.across_seeds(scores, reps=REPS)
    monkeypatch.setitem(sys.modules, "rliable", None)  # import rliable now raises
    assert aggregate.across_seeds(scores, reps=REPS) == before


@pytest.mark.slow
def test_ray_seeds_equal_local_seeds(seeds_run, tmp_path):
    pytest.importorskip("ray")
    out = tmp_path / "ray"
    result = train_seeds(
        "BallTable-v0", "ppo", "state", out, [1], backend="ray", progress=False, reps=REPS,
        **OPTIONS,
    )  # fmt: skip
    assert result.status == "finished"
    for a, b in zip(
        _parameters(out / "seed_1" / "model.zip"),
        _parameters(seeds_run / "seed_1" / "model.zip"),
        strict=True,
    ):
        np.testing.assert_array_equal(a, b)


@pytest.mark.slow
def test_a_killed_multi_seed_run_keeps_each_checkpoint_and_resumes(tmp_path):
    """SIGTERM to 'observer-gym train --seeds 0,1' while both train: exit code 130, each
    seed interrupted with its last checkpoint, and --resume finishes both."""
    out = tmp_path / "out"
    command = [
        sys.executable, "-m", "observer_gym.train.cli", "train", "--env", "BallTable-v0",
        "--algo", "ppo", "--obs", "state", "--seeds", "0,1", "--workers", "2",
        "--timesteps", "200000", "--n-envs", "1", "--vec-env", "dummy",
        "--hyperparam", "n_steps=256", "--hyperparam", "checkpoint_freq=256",
        "--hyperparam", "eval_freq=100000", "--out", str(out), "--no-progress",
    ]  # fmt: skip
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + 300
        while not all(latest_checkpoint(out / f"seed_{s}" / "checkpoints") for s in (0, 1)):
            assert process.poll() is None, process.stdout.read().decode()
            assert time.monotonic() < deadline, "no checkpoints within 300 s"
            time.sleep(0.5)
        os.kill(process.pid, signal.SIGTERM)
        output, _ = process.communicate(timeout=120)
    finally:
        process.kill()
    assert process.returncode == 130, output.decode()
    assert "--resume" in output.decode()
    targets = []
    for seed in (0, 1):
        run = out / f"seed_{seed}"
        state = json.loads((run / "state.json").read_text())
        assert state["status"] == "interrupted", output.decode()
        saved = latest_checkpoint(run / "checkpoints")
        assert saved["timesteps"] == state["last_checkpoint_timesteps"] > 0
        targets.append(state["timesteps"])
    target = max(targets) + 256
    argv = ["train", "--resume", str(out), "--timesteps", str(target), "--no-progress"]
    assert main(argv) == 0
    for seed in (0, 1):
        state = json.loads((out / f"seed_{seed}" / "state.json").read_text())
        assert state["status"] == "finished" and state["timesteps"] >= target
    assert (out / "aggregate.json").is_file()
