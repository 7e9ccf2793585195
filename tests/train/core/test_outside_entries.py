"""Observers and controllers from outside the package in run, compare and sweep: by
import path, by entry point and as Python objects; bad entries fail in one line before
anything is written; a fault part-way names the episode and keeps finished cells."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from outside_package import PACKAGE, VERSION, forget_package, write_package

import observer_gym
from observer_gym.train.cli import main
from observer_gym.train.core import entries
from observer_gym.train.experiments.episode import EpisodeSpec, run_episode

ENV = "BallTable-v0"
STEPS = 60
OBSERVER = f"{PACKAGE}.filters:make_observer-measurements"
DELEGATE = f"{PACKAGE}.filters:make_delegate"
CONTROLLER = f"{PACKAGE}.control:make_controller_"


@pytest.fixture
def installed(tmp_path, monkeypatch):
    """The package installed with its entry points (its dist-info on sys.path)."""
    root = write_package(tmp_path / "site", entry_points=True)
    monkeypatch.syspath_prepend(str(root))
    forget_package()
    entries.refresh()
    yield root
    forget_package()
    monkeypatch.undo()
    entries.refresh()


def _metrics(pair):
    return {k: v for k, v in pair.statistics.items() if v["mean"] is not None}


@pytest.mark.slow  # 58 s at load 7
def test_outside_entries_run_beside_the_builtins_and_give_their_numbers(outside, tmp_path):
    # An observer that passes kf through and a controller that is the LQR at gain 1 must
    # give exactly kf's and the LQR's numbers: the machinery adds nothing of its own.
    result = observer_gym.compare(
        ENV,
        ["kf", DELEGATE.replace("make_delegate", "make_delegate")],
        ["lqr", CONTROLLER],
        seeds=[3, 4],
        steps=STEPS,
        workers=2,
        out_dir=tmp_path / "cmp",
    )
    by_pair = {(p.observer, p.controller): p for p in result.pairs}
    reference = _metrics(by_pair["kf", "lqr"])
    for pair in result.pairs:
        assert _metrics(pair) == reference, (pair.observer, pair.controller)
    written = json.loads((tmp_path / "cmp" / "results.json").read_text())
    outside_pair = next(p for p in written["pairs"] if p["observer"] == DELEGATE)
    assert outside_pair["entry"]["import_path"] == f"{PACKAGE}.filters:make_delegate"
    assert outside_pair["entry"]["version"] == "not installed"
    assert outside_pair["obs_mode"] == "rgb"
    controller_pair = next(p for p in written["pairs"] if p["controller"] == CONTROLLER)
    assert controller_pair["controller_config"]["entry"]["package"] == PACKAGE
    table = (tmp_path / "cmp" / "table.md").read_text()
    assert f"- observer {DELEGATE} ({PACKAGE} not installed)" in table


@pytest.mark.slow  # two worker processes and two runs: 7.8 s (load ~2)
def test_an_alpha_beta_observer_runs_with_its_options_and_one_worker_equals_two(outside, tmp_path):
    runs = [
        observer_gym.run(
            ENV,
            OBSERVER,
            CONTROLLER,
            episodes=2,
            seed=5,
            steps=STEPS,
            workers=workers,
            out_dir=tmp_path / f"w{workers}",
            observer_options={"alpha": 0.7},
            controller_options={"gain": 0.8},
        )
        for workers in (1, 2)
    ]
    assert runs[0].episodes == runs[1].episodes
    config = runs[0].results["config"]
    assert config["entry"]["options"] == {"alpha": 0.7}
    assert config["env_kwargs"]["obs_mode"] == "measurements"
    assert config["controller_config"]["entry"]["options"] == {"gain": 0.8}
    # the ball is estimated from the detections: within a few millimetres of the truth
    assert 0 < runs[0].summary["position_rmse_m"] < 5e-3
    assert "controller obslab.control:make_controller_ (obslab not installed" in runs[0].text


@pytest.mark.slow  # 27 s at load 7
def test_a_sweep_takes_outside_entries_and_their_options(outside, tmp_path):
    out = tmp_path / "sweep"
    argv = [
        "sweep", "--env", ENV, "--vary", "latency_s=0,0.05",
        "--observers", f"kf-measurements,{OBSERVER}", "--controllers", CONTROLLER,
        "--episodes", "2", "--steps", str(STEPS), "--workers", "2", "--out", str(out),
        "--observer-option", "alpha=0.6", "--no-progress",
    ]  # fmt: skip
    assert main(argv) == 0
    results = json.loads((out / "results.json").read_text())
    outside_cells = [c for c in results["cells"] if c["observer"] == OBSERVER]
    assert len(outside_cells) == 2
    assert all(c["entry"]["options"] == {"alpha": 0.6} for c in outside_cells)
    assert all("entry" not in c for c in results["cells"] if c["observer"] == "kf-measurements")
    assert "--observer-option alpha=0.6" in results["config"]["command"]
    # the same command resumes: every cell is reused
    assert main(argv) == 0
    timing = json.loads((out / "timing.json").read_text())
    assert timing["cells_run"] == 0 and timing["cells_reused"] == 4


def test_entries_installed_by_a_package_are_listed_and_taken_by_name(
    installed, tmp_path, capsys, monkeypatch
):
    monkeypatch.setenv("COLUMNS", "400")  # --help on long lines: no hyphen broken
    with pytest.raises(SystemExit):
        main(["sweep", "--help"])
    shown = " ".join(capsys.readouterr().out.split())
    assert "(installed: alpha-beta)" in shown and "(installed: scaled-lqr)" in shown
    assert main(["list", "observer"]) == 0
    listed = capsys.readouterr().out
    (line,) = [text for text in listed.splitlines() if text.split()[0] == "alpha-beta"]
    assert f"{PACKAGE}.filters:make_observer ({VERSION})" in line
    assert line.endswith(f"[entry point of {PACKAGE}]")
    argv = [
        "run", "--env", ENV, "--observer", "alpha-beta-measurements",
        "--controller", "scaled-lqr", "--controller-option", "gain=0.9",
        "--episodes", "1", "--steps", "20", "--out", str(tmp_path / "run"), "--no-progress",
    ]  # fmt: skip
    assert main(argv) == 0
    config = json.loads((tmp_path / "run" / "results.json").read_text())["config"]
    assert config["entry"]["source"] == f"entry point of {PACKAGE}"
    assert config["entry"]["version"] == VERSION
    assert (
        config["controller_config"]["entry"]["import_path"] == f"{PACKAGE}.control:make_controller_"
    )


# --- bad entries: one line and exit 2 from the command, ValueError from Python ------------
BAD_OBSERVERS = [
    (f"{PACKAGE}.broken:make-measurements", "cannot import 'obslab.broken': ImportError"),
    (f"{PACKAGE}.filters:missing-measurements", "has no attribute 'missing'"),
    (f"{PACKAGE}.filters:NOT_CALLABLE-measurements", "is a int, not a factory"),
    (f"{PACKAGE}.filters:raises-measurements", "raised RuntimeError: calibration file missing"),
    (f"{PACKAGE}.filters:no_observe-measurements", "without reset(), observe()"),
    (f"{PACKAGE}.filters:wrong_layout-measurements", "a mean of shape (8,)"),
    (f"{PACKAGE}.filters:not_an_estimate-measurements", "must return an observer_gym"),
    ("nosuchlab.filters:make", "No module named 'nosuchlab'"),
]
BAD_CONTROLLERS = [
    (f"{PACKAGE}.control:wrong_shape", "of shape (2,)"),
    (f"{PACKAGE}.control:nan_action", "non-finite action"),
    (f"{PACKAGE}.control:not_a_tuple", "must return (action, state)"),
]


@pytest.mark.parametrize(("observer", "message"), BAD_OBSERVERS)
def test_a_bad_observer_is_one_line_before_anything_runs(
    outside, tmp_path, capsys, observer, message
):
    out = tmp_path / "out"
    argv = ["--env", ENV, "--controller", "lqr", "--steps", "5", "--out", str(out)]
    assert main(["run", "--observer", observer, *argv, "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err and observer.split("-")[0] in err
    assert not out.exists()
    with pytest.raises(ValueError, match="observer"):
        observer_gym.run(ENV, observer, "lqr", episodes=1, steps=5, out_dir=out)
    assert not out.exists()


@pytest.mark.parametrize(("controller", "message"), BAD_CONTROLLERS)
def test_a_bad_controller_is_one_line_before_anything_runs(
    outside, tmp_path, capsys, controller, message
):
    out = tmp_path / "out"
    argv = ["--observers", "kf-measurements", "--controllers", f"lqr,{controller}"]
    assert main(["compare", "--env", ENV, *argv, "--steps", "5", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err and controller in err
    assert not out.exists()
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        observer_gym.compare(ENV, "kf-measurements", controller, seeds=[0], steps=5, out_dir=out)


def test_options_without_an_outside_entry_are_refused(capsys, tmp_path):
    argv = ["run", "--observer", "kf", "--controller", "lqr", "--observer-option", "alpha=1"]
    assert main([*argv, "--out", str(tmp_path / "x")]) == 2
    assert "apply to outside observers" in capsys.readouterr().err


def test_a_fault_part_way_names_the_episode_and_keeps_the_finished_cells(outside, tmp_path, capsys):
    late = f"{PACKAGE}.filters:nan_after-measurements"
    out = tmp_path / "sweep"
    argv = [
        "sweep", "--env", ENV, "--vary", "latency_s=0", "--observers",
        f"kf-measurements,{late}", "--controllers", "lqr", "--episodes", "2", "--seed", "9",
        "--steps", str(STEPS), "--out", str(out), "--no-progress",
    ]  # fmt: skip
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "the estimate is not finite" in err
    assert "episode seed 9, after 39 steps" in err
    finished = list((out / "cells").glob("*.json"))
    assert len(finished) == 1  # kf-measurements' cell, whole, for a resume
    assert json.loads(finished[0].read_text())["observer"] == "kf-measurements"
    assert not (out / "results.json").exists()


# --- Python objects ------------------------------------------------------------------------
class _Gain:
    """A controller object: the LQR's action halved."""

    def __init__(self, env):
        from observer_gym.controllers import make_controller

        self.lqr = make_controller("lqr", env)

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        action, _ = self.lqr.predict(obs)
        return 0.5 * np.asarray(action), state


@pytest.mark.slow  # 34 s at load 7
def test_factories_and_objects_from_python(outside, tmp_path):
    from obslab.filters import make_observer

    make_observer.obs_mode = "measurements"
    result = observer_gym.compare(
        ENV,
        [make_observer, "kf-measurements"],
        [_Gain, "lqr"],
        seeds=[1],
        steps=STEPS,
        workers=2,
        out_dir=tmp_path / "objects",
    )
    names = {(p.observer, p.controller) for p in result.pairs}
    assert (OBSERVER, f"{__name__}:_Gain") in names
    halved = next(p for p in result.pairs if p.controller.endswith("_Gain"))
    full = next(p for p in result.pairs if p.controller == "lqr" and p.observer == halved.observer)
    effort = "effort_rms_rad"
    assert halved.statistics[effort]["mean"] < full.statistics[effort]["mean"]


def test_an_object_that_does_not_pickle_is_refused_before_the_workers_start(tmp_path):
    def local_factory(env):  # a closure: no import path, does not pickle
        return _Gain(env)

    with pytest.raises(ValueError, match="cannot run in workers: it does not pickle"):
        observer_gym.compare(
            ENV, "oracle", local_factory, seeds=[0, 1], workers=2, out_dir=tmp_path / "no"
        )
    assert not (tmp_path / "no").exists()
    result = observer_gym.run(  # in this process it runs
        ENV, "oracle", local_factory, episodes=1, steps=10, out_dir=tmp_path / "yes"
    )
    assert result.results["config"]["controller"].startswith("python:")


# --- a policy trained outside observer-gym ---------------------------------------------------
@pytest.mark.slow  # a training, 15 s at load 7
def test_a_policy_zip_trained_with_plain_stable_baselines3_is_compared(tmp_path, capsys):
    import gymnasium as gym
    from stable_baselines3 import PPO

    env = gym.make("observer_gym/BallTable-v0", obs_mode="state")
    model = PPO("MlpPolicy", env, n_steps=64, batch_size=32, n_epochs=1, seed=0, device="cpu")
    model.learn(128)
    env.close()
    path = tmp_path / "elsewhere" / "policy.zip"
    path.parent.mkdir()
    model.save(path)
    out = tmp_path / "cmp"
    argv = ["compare", "--env", ENV, "--observers", "kf-measurements", "--controllers"]
    assert main([*argv, f"ppo:{path},lqr", "--seeds", "2", "--steps", "20", "--out", str(out)]) == 0
    results = json.loads((out / "results.json").read_text())
    pair = next(p for p in results["pairs"] if p["controller"] == f"ppo:{path}")
    assert pair["controller_config"]["class"] == "PolicyFile"
    # the actions are the policy's own on the estimates it was given (deterministic)
    spec = EpisodeSpec.of(
        "observer_gym/BallTable-v0", "kf-measurements", f"ppo:{path}", 2, max_steps=10
    )
    record = run_episode(spec)
    expected, _ = model.predict(record["estimate"][:10].astype(np.float32), deterministic=True)
    np.testing.assert_allclose(record["actions"], expected, rtol=1e-5, atol=1e-9)
    # a zip of another algorithm, or not a model at all, is one line and exit 2
    capsys.readouterr()
    not_a_model = tmp_path / "notes.zip"
    not_a_model.write_bytes(b"PK\x05\x06" + bytes(18))  # an empty zip archive
    assert main([*argv, f"ppo:{not_a_model}", "--steps", "5", "--out", str(tmp_path / "n")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "is not a stable-baselines3 model" in err
    assert main([*argv, f"sac:{path}", "--steps", "5", "--out", str(tmp_path / "s")]) == 2
    assert "sac cannot load it" in capsys.readouterr().err


def test_list_has_one_line_for_every_system_observer_controller_and_shipped_agent(capsys):
    from observer_gym.train.core.systems import system_entries
    from observer_gym.train.rl.shipped import shipped_names

    assert main(["list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    named = {line.split()[0]: line for line in lines if line.startswith("  ")}
    for entry in system_entries():
        assert entry.system.short_id in named
        for name in (*entry.observers, *entry.controllers):
            # a summary after the name, and the env among those it applies to
            assert len(named[name].split()) > 3 and entry.system.short_id in named[name]
    for name in shipped_names():
        assert any(key.endswith(f":{name}") for key in named)
    assert observer_gym.compare is observer_gym.train.experiments.api.compare


# --- the tutorial's package (docs/your_method.md) ------------------------------------------
EXAMPLE = Path(__file__).resolve().parents[3] / "examples" / "your_method"


def test_the_tutorials_alpha_beta_covariance_is_the_closed_form(monkeypatch):
    # Benedict-Bordner: a fixed-gain alpha-beta filter's steady-state error variances under
    # white measurement noise sigma^2 are sigma^2 (2 a^2 + 2 b - 3 a b) / (a (4 - 2 a - b))
    # for the position and sigma^2 2 b^2 / (T^2 a (4 - 2 a - b)) for the velocity.
    import gymnasium as gym

    monkeypatch.syspath_prepend(str(EXAMPLE))
    from mylab.filters import make_observer

    env = gym.make("observer_gym/BallTable-v0", obs_mode="measurements", measurement_noise_px=1.0)
    alpha, beta = 0.6, 0.25
    pipeline = make_observer(env.unwrapped, alpha=alpha, beta=beta)
    pipeline.reset()
    obs, info = env.reset(seed=0)
    estimate = pipeline.observe(obs, info, None)
    obs, *_, info = env.step(np.zeros(2))
    detection_var = pipeline.detector.observe(obs, info, np.zeros(2)).covariance[0, 0]
    estimate = pipeline.observe(obs, info, np.zeros(2))
    env.close()
    dt = env.unwrapped.dt_s
    denominator = alpha * (4 - 2 * alpha - beta)
    position = detection_var * (2 * alpha**2 + 2 * beta - 3 * alpha * beta) / denominator
    velocity = detection_var * 2 * beta**2 / (dt**2 * denominator)
    np.testing.assert_allclose(estimate.covariance[0, 0], position, rtol=1e-9)
    np.testing.assert_allclose(estimate.covariance[2, 2], velocity, rtol=1e-9)


@pytest.mark.slow  # 20 s at load 7
def test_the_tutorials_sweep_runs_from_python(tmp_path):
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(EXAMPLE), os.environ.get("PYTHONPATH", "")]),
    }
    argv = ["--out", str(tmp_path / "s"), "--episodes", "1", "--steps", "5", "--workers", "1"]
    done = subprocess.run(
        [sys.executable, str(EXAMPLE / "sweep.py"), *argv], env=env, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
    results = json.loads((tmp_path / "s" / "results.json").read_text())
    observers = {cell["observer"] for cell in results["cells"]}
    assert observers == {
        "kf-measurements",
        "ekf-measurements",
        "mylab.filters:make_observer-measurements",
    }
    assert len(results["cells"]) == 24


@pytest.mark.slow  # a training, 21 s at load 7
def test_an_agent_trains_on_an_outside_observers_estimate(outside, tmp_path):
    out = tmp_path / "agent"
    argv = [
        "train", "--env", ENV, "--algo", "ppo", "--obs", "estimate", "--observer", OBSERVER,
        "--timesteps", "64", "--n-envs", "1", "--hyperparam", "n_steps=32",
        "--hyperparam", "batch_size=32", "--hyperparam", "eval_freq=10000",
        "--out", str(out), "--no-progress",
    ]  # fmt: skip
    assert main(argv) == 0
    config = json.loads((out / "config.json").read_text())
    assert config["observer"] == OBSERVER
    # and the agent runs behind the same outside observer
    result = observer_gym.run(
        ENV, OBSERVER, f"ppo:{out}", episodes=1, steps=10, out_dir=tmp_path / "eval"
    )
    assert result.results["config"]["entry"]["import_path"] == f"{PACKAGE}.filters:make_observer"
