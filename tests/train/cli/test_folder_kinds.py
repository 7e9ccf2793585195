"""run and compare refuse a folder holding another command's results, as sweep and train
do: one line, exit 2, and the other command's files untouched."""

from __future__ import annotations

import json

import pytest

from observer_gym.train.cli import main
from observer_gym.train.experiments.compare import run_comparison
from observer_gym.train.experiments.run import run_experiment
from observer_gym.train.reports.outputs import folder_kind

TINY = ["--env", "BallTable-v0", "--steps", "5", "--no-progress"]


def _sweep(out):
    argv = ["sweep", *TINY, "--vary", "latency_s=0", "--observers", "oracle"]
    assert main([*argv, "--controllers", "lqr", "--episodes", "1", "--out", str(out)]) == 0


def _compare(out):
    argv = ["compare", *TINY, "--observers", "oracle", "--controllers", "lqr"]
    assert main([*argv, "--episodes", "1", "--out", str(out)]) == 0


def _run(out):
    argv = ["run", *TINY, "--observer", "oracle", "--controller", "lqr"]
    assert main([*argv, "--episodes", "1", "--out", str(out)]) == 0


def _train(out):  # what a training run leaves before its first checkpoint
    out.mkdir()
    (out / "config.json").write_text(json.dumps({"algo": "ppo"}))


@pytest.mark.parametrize(
    ("make", "kind"), [(_sweep, "sweep"), (_compare, "compare"), (_train, "train")]
)
def test_run_refuses_another_commands_folder(tmp_path, capsys, make, kind):
    out = tmp_path / "out"
    make(out)
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    capsys.readouterr()
    argv = ["run", *TINY, "--observer", "oracle", "--controller", "lqr", "--out", str(out)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"holds 'observer-gym {kind}' results" in err
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    with pytest.raises(ValueError, match="use another output folder"):
        run_experiment("BallTable-v0", "oracle", "lqr", 1, 0, out, steps=5, progress=False)


@pytest.mark.parametrize(("make", "kind"), [(_sweep, "sweep"), (_run, "run"), (_train, "train")])
def test_compare_refuses_another_commands_folder(tmp_path, capsys, make, kind):
    out = tmp_path / "out"
    make(out)
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    capsys.readouterr()
    argv = ["compare", *TINY, "--observers", "oracle", "--controllers", "lqr", "--out", str(out)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"holds 'observer-gym {kind}' results" in err
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    with pytest.raises(ValueError, match="use another output folder"):
        run_comparison("BallTable-v0", "oracle", "lqr", [0], out, steps=5, progress=False)


@pytest.mark.slow  # every command twice: 6.4 s (load ~2)
def test_a_command_writes_again_into_its_own_folder(tmp_path):
    out = tmp_path / "out"
    _run(out)
    assert folder_kind(out) == "run"
    _run(out)  # the same command again: allowed, as before
    _compare(tmp_path / "cmp")
    _compare(tmp_path / "cmp")
    assert folder_kind(tmp_path / "cmp") == "compare"
