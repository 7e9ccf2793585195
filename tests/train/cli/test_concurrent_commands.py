"""Two real ``observer-gym`` commands racing into one folder (issue 29, items 3 and 4).
The first is paused (tests/train/paused_command.py) at the last moment before it writes
what the second's checks read: a new run's config.json, a resumed run's state.json and
logs, a new sweep's sweep.json. Before the lock, the second passed its checks and wrote
into the same folder (interleaved progress.csv and eval.csv rows; one sweep's folder
holding both sweeps' cells); now it is refused with one line and exit code 75, and the
first carries on alone. Each starts a child process that imports the whole stack, so
they are slow tests; tests/train/reports/test_folder_lock.py refuses every command against a
light lock-holding process in the default run."""

from __future__ import annotations

import json
import shutil
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from observer_gym.train.cli import main
from observer_gym.train.rl import training
from observer_gym.train.rl.training import train_agent

PAUSED = Path(__file__).parents[1] / "paused_command.py"
READY_TIMEOUT_S = 180.0
TINY = {"n_steps": 64, "batch_size": 64, "checkpoint_freq": 64, "eval_freq": 10_000,
        "eval_episodes": 1}  # fmt: skip
TRAIN = ["train", "--algo", "ppo", "--obs", "state", "--timesteps", "64", "--n-envs", "1",
         "--vec-env", "dummy", "--hyperparam", "n_steps=64", "--hyperparam", "batch_size=64",
         "--hyperparam", "eval_freq=10000", "--no-progress"]  # fmt: skip
SWEEP = ["sweep", "--observers", "oracle", "--controllers", "lqr", "--episodes", "1",
         "--steps", "3", "--no-progress"]  # fmt: skip


class Paused:
    """The first command, in a child process, paused at ``point`` until :meth:`go`."""

    def __init__(self, folder: Path, point: str, argv: list[str]) -> None:
        self.ready, self.gate = folder / "ready", folder / "go"
        self.process = subprocess.Popen(
            [sys.executable, str(PAUSED), point, str(self.ready), str(self.gate), *argv],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        deadline = time.monotonic() + READY_TIMEOUT_S
        while not self.ready.exists():
            if self.process.poll() is not None:
                raise AssertionError(f"the first command ended: {self.process.communicate()}")
            assert time.monotonic() < deadline, "the first command did not reach its pause"
            time.sleep(0.02)

    def go(self) -> tuple[int, str]:
        """Let it carry on; its exit code and stderr."""
        self.gate.touch()
        _, err = self.process.communicate(timeout=300)
        return self.process.returncode, err

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
            self.process.communicate()


@pytest.fixture
def paused() -> Iterator[list[Paused]]:
    started: list[Paused] = []
    yield started
    for first in started:
        first.close()


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory) -> Path:
    """A finished 64-step PPO run (one checkpoint)."""
    out = tmp_path_factory.mktemp("run") / "run"
    train_agent("BallTable-v0", "ppo", "state", out, timesteps=64, n_envs=1, vec_env="dummy",
                hyperparams=TINY, progress=False)  # fmt: skip
    return out


def refused_line(capsys, command: str, folder: Path, first: Paused) -> str:
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith(f"observer-gym {command.split()[0]}: error: {folder} is in use by ")
    assert f"'observer-gym {command}' (pid {first.process.pid} on {socket.gethostname()}" in line
    return line


def stub_learn(monkeypatch) -> list[Path]:
    """training.learn recording its calls instead of training."""
    calls: list[Path] = []

    def learn(run_dir, config, progress, checkpoint=None):
        calls.append(run_dir)
        return {"status": "finished", "timesteps": 64, "target_timesteps": 64,
                "last_checkpoint_timesteps": 64, "segment_steps": 0, "segment_wall_time_s": 0.0,
                "segment_eval_time_s": 0.0, "train_steps_per_s": 0.0}  # fmt: skip

    monkeypatch.setattr(training, "learn", learn)
    return calls


@pytest.mark.slow  # two trainings and a child process importing PyTorch: 10-20 s
def test_a_second_resume_of_a_run_is_refused(finished_run, tmp_path, paused, monkeypatch, capsys):
    run = tmp_path / "run"
    shutil.copytree(finished_run, run)
    argv = ["train", "--resume", str(run), "--timesteps", "128", "--no-progress"]
    first = Paused(tmp_path, "train-learn", argv)  # checked, about to train
    paused.append(first)
    calls = stub_learn(monkeypatch)
    assert main(argv) == 75
    assert calls == []  # it never started training
    refused_line(capsys, "train --resume", run, first)
    code, err = first.go()
    assert code == 0, err
    state = json.loads((run / "state.json").read_text())
    assert state["status"] == "finished" and state["timesteps"] == 128
    # one segment per training: the second wrote no logs, no eval.csv rows of its own
    assert sorted(p.name for p in (run / "logs").iterdir()) == ["resume-64", "start"]


@pytest.mark.slow  # two trainings' probe envs and a child importing PyTorch: 10-20 s
def test_a_second_new_training_run_into_one_folder_is_refused(tmp_path, paused, monkeypatch,
                                                              capsys):  # fmt: skip
    out = tmp_path / "run"
    first = Paused(tmp_path, "train-config", [*TRAIN, "--out", str(out)])  # before config.json
    paused.append(first)
    calls = stub_learn(monkeypatch)
    assert main([*TRAIN, "--out", str(out)]) == 75
    assert calls == [] and not (out / "config.json").exists()
    refused_line(capsys, "train", out, first)
    code, err = first.go()
    assert code == 0, err
    assert json.loads((out / "state.json").read_text())["status"] == "finished"


@pytest.mark.slow  # a child process importing the layers and two checks: about 8 s
def test_a_second_sweep_into_one_new_folder_is_refused(tmp_path, paused, capsys):
    """Two sweeps with different --vary into one new --out: before, both passed the check
    (no sweep.json yet) and the folder held both sweeps' cells."""
    out = tmp_path / "sweep"
    first = Paused(tmp_path, "sweep-arguments",
                   [*SWEEP, "--vary", "measurement_noise_px=0", "--out", str(out)])  # fmt: skip
    paused.append(first)
    assert main([*SWEEP, "--vary", "measurement_noise_px=2", "--out", str(out)]) == 75
    refused_line(capsys, "sweep", out, first)
    assert not (out / "sweep.json").exists() and not (out / "cells").exists()
    code, err = first.go()
    assert code == 0, err
    arguments = json.loads((out / "sweep.json").read_text())["arguments"]
    assert arguments["vary"] == {"measurement_noise_px": [0.0]}
    cells = [p.name for p in (out / "cells").glob("*.json")]
    assert len(cells) == 1 and cells[0].startswith("measurement_noise_px-0.0__")
    # and after it, the other sweep is refused as another sweep's folder: exit code 2
    assert main([*SWEEP, "--vary", "measurement_noise_px=2", "--out", str(out)]) == 2
    assert "holds a sweep with other arguments" in capsys.readouterr().err
