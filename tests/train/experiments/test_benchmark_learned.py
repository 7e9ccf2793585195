"""The learned observers (``learned``, ``learned-kf``) on the benchmark: their leaderboard
kind, their refusal without PyTorch, (slow) a quick run of each on every system, and their
published rows (docs/results/benchmark/v1/<system>/learned*-measurements--<reference>/)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from observer_gym import extras
from observer_gym.extras import RL_INSTALL
from observer_gym.train.cli import main
from observer_gym.train.experiments.benchmark.leaderboard import Row, read_rows, slug
from observer_gym.train.experiments.benchmark.suite import load_suite

REPO = Path(__file__).resolve().parents[3]
ROOT = REPO / "docs" / "results" / "benchmark" / "v1"
PAGE = REPO / "docs" / "leaderboard.md"
ENVS = ("BallTable-v0", "BallCatcher-v1", "TargetFollower-v0")
LEARNED = ("learned-measurements", "learned-kf-measurements")


def _row(observer: str, controller: str) -> Row:
    return Row(
        folder=Path("x"),
        suite="v1",
        env="observer_gym/BallTable-v0",
        observer=observer,
        controller=controller,
        command="",
        levels=(),
        iqm=(0.0, 0.0, 0.0),
        version="0",
    )


@pytest.mark.parametrize(
    ("observer", "controller", "kind"),
    [
        ("learned", "lqr", "learned"),
        ("learned-measurements", "lqr", "learned"),
        ("learned-kf", "intercept", "learned"),
        ("learned-kf-measurements", "vtc", "learned"),
        # a trained policy is an agent whatever it reads
        ("learned-kf-measurements", "ppo:ball_catcher-estimate-learned-kf", "agent"),
        ("kf-measurements", "lqr", "classical"),
        ("ekf", "lqr", "classical"),
        ("oracle-visible-measurements", "lqr", "true state"),
        ("oracle", "lqr", "true state"),
        # a name that only begins like a learned family is not one
        ("learned-kf-latency-measurements", "lqr", "classical"),
        ("mylab.learned:make_observer-measurements", "lqr", "classical"),
    ],
)
def test_a_rows_kind_names_the_learned_families(observer, controller, kind):
    assert _row(observer, controller).kind == kind


@pytest.mark.parametrize("env_id", ENVS)
@pytest.mark.parametrize("observer", LEARNED)
def test_without_pytorch_the_benchmark_refuses_a_learned_observer_in_one_line(
    env_id, observer, tmp_path, monkeypatch, capsys
):
    real = extras.missing_modules
    monkeypatch.setattr(
        extras,
        "missing_modules",
        lambda modules: ["torch", *real(m for m in modules if m != "torch")],
    )
    controller = load_suite(env_id).controller
    out = tmp_path / "out"
    argv = ["benchmark", "--env", env_id, "--observer", observer, "--controller", controller,
            "--episodes", "1", "--no-progress", "--out", str(out)]  # fmt: skip
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err == (
        f"observer-gym benchmark: error: observer {observer!r} needs PyTorch, which is not "
        f"installed: {RL_INSTALL}\n"
    )
    assert not out.exists()  # refused before any env or output folder


@pytest.mark.slow
@pytest.mark.parametrize("env_id", ENVS)
@pytest.mark.parametrize("observer", LEARNED)
def test_a_quick_run_of_a_learned_observer_checks_out(env_id, observer, tmp_path, capsys):
    controller = load_suite(env_id).controller
    out = tmp_path / "run"
    argv = ["benchmark", "--env", env_id, "--observer", observer, "--controller", controller,
            "--episodes", "1", "--no-progress", "--out", str(out)]  # fmt: skip
    assert main(argv) == 0
    scores = json.loads((out / "scores.json").read_text())
    assert (scores["observer"], scores["controller"], scores["official"]) == (
        observer, controller, False
    )  # fmt: skip
    assert scores["packages"]["torch"] not in ("", "not installed")
    capsys.readouterr()
    assert main(["benchmark", "--check", str(out)]) == 0
    assert "OK" in capsys.readouterr().out


def test_every_system_has_a_published_learned_row_of_each_family():
    rows = {(row.env, row.observer, row.controller): row for row in read_rows(ROOT, verify=False)}
    page = PAGE.read_text(encoding="utf-8")
    for env_id in ENVS:
        suite = load_suite(env_id)
        for observer in LEARNED:
            row = rows[(f"observer_gym/{env_id}", observer, suite.controller)]
            assert row.folder == ROOT / suite.system.name / slug(observer, suite.controller)
            assert row.kind == "learned"
            line = f"| `{observer}` | `{suite.controller}` | learned | "
            assert line in page, f"{env_id}: no row {line!r} on {PAGE}"
