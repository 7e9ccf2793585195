"""``observer-gym compare``: every (observer, controller) pair on the same seeds, its
statistics, the oracle difference, the outputs, the backends and the command line."""

from __future__ import annotations

import argparse
import csv
import json
import math
import shlex
import sys
from pathlib import Path
from types import SimpleNamespace

import cv2
import gymnasium
import numpy as np
import pytest
from scipy import stats

from observer_gym.envs.ball_catcher import MISS_REASONS
from observer_gym.train.cli import compare as compare_cli
from observer_gym.train.core.args import env_option
from observer_gym.train.core.tasks import ball_catcher, ball_table
from observer_gym.train.core.tasks.ball_table import COMPARE_METRICS
from observer_gym.train.experiments import ray_backend, request
from observer_gym.train.experiments.benchmark.suite import load_suite
from observer_gym.train.experiments.compare import command_line, run_comparison
from observer_gym.train.experiments.run import run_experiment
from observer_gym.train.reports import compare_report
from observer_gym.train.reports.compare_report import format_seeds, pair_folders, safe_name
from observer_gym.train.reports.compare_stats import (
    mean_interval,
    metric_statistics,
    paired_difference,
    rate_interval,
)

OBSERVERS = ["oracle", "kf-measurements"]
CONTROLLERS = ["lqr", "pid"]
SEEDS = [3, 4, 5]
STEPS = 100
PRIMARY = "mean_distance_m"


def check_plot(path: Path) -> None:
    image = cv2.imread(str(path))
    assert image is not None, f"{path} is missing or not an image"
    assert image.shape[0] > 200 and image.shape[1] > 200


def table_rows(markdown: str) -> list[list[str]]:
    """The cells of every line of the Markdown table, header first (rule left out)."""
    lines = [line for line in markdown.splitlines() if line.startswith("|")]
    return [[c.strip() for c in line.strip("|").split("|")] for line in lines if "---" not in line]


def pair(results: dict, observer: str, controller: str) -> dict:
    (found,) = [
        p for p in results["pairs"] if p["observer"] == observer and p["controller"] == controller
    ]
    return found


@pytest.fixture(scope="module")
def compared(tmp_path_factory) -> tuple[Path, dict]:
    out_dir = tmp_path_factory.mktemp("compare")
    results = run_comparison(
        "BallTable-v0",
        OBSERVERS,
        CONTROLLERS,
        SEEDS,
        out_dir,
        steps=STEPS,
        progress=False,
        cli_args={"from": "test"},
    )
    return out_dir, results


def test_compare_writes_the_table_csv_plots_and_results(compared):
    out_dir, results = compared
    assert json.loads((out_dir / "results.json").read_text()) == results
    assert not [p.name for p in out_dir.iterdir() if p.name.endswith(".tmp")]
    assert results["config"]["seeds"] == SEEDS and results["config"]["primary_metric"] == PRIMARY

    text = (out_dir / "table.md").read_text()
    assert text.splitlines()[0] == f"`{results['config']['command']}`"
    header, *rows = table_rows(text)
    assert len(rows) == 4
    assert header[-2:] == ["Δ distance from centre vs oracle (mm)", "NEES/dof [95 % band]"]
    assert [(r[0], r[1]) for r in rows] == [(o, c) for c in CONTROLLERS for o in OBSERVERS]
    for row in rows:
        assert len(row) == len(header) == 2 + len(COMPARE_METRICS) + 2
        assert (row[-2] == "reference") == (row[0] == "oracle")
        episodes = pair(results, row[0], row[1])["episodes"]
        if row[0] == "oracle":
            assert row[-1] == "n/a"
            continue
        # The episodes' summed NEES over their summed dof, inside or outside the chi-square
        # band of that many dof.
        nees = sum(e["nees_mean"] for e in episodes)
        dof = sum(e["nees_dof"] for e in episodes)
        low, high = (stats.chi2.ppf(q, dof) / dof for q in (0.025, 0.975))
        mark = "" if low <= nees / dof <= high else " ⚠"
        assert row[-1] == f"{nees / dof:.2f}{mark} [{low:.2f}, {high:.2f}]"

    with (out_dir / "table.csv").open() as f:
        csv_rows = list(csv.DictReader(f))
    assert len(csv_rows) == 4 * len(COMPARE_METRICS) + len(CONTROLLERS)
    for row in csv_rows:
        if row["metric"] == f"{PRIMARY}_minus_oracle":
            expected = pair(results, row["observer"], row["controller"])["vs_oracle"]
        else:
            expected = pair(results, row["observer"], row["controller"])["statistics"][
                row["metric"]
            ]
        assert int(row["n"]) == expected["n"]
        assert float(row["mean"]) == expected["mean"]

    for key in COMPARE_METRICS:
        check_plot(out_dir / f"bar_{key}.png")
    for p in results["pairs"]:
        assert p["files"] and all(name.startswith(f"pairs/{p['folder']}/") for name in p["files"])
        for name in p["files"]:
            check_plot(out_dir / name)
    assert set(results["files"]) >= {"table.md", "table.csv", "results.json"}


def test_every_pair_runs_the_same_seeds_as_observer_gym_run(compared, tmp_path):
    _, results = compared
    # Episode i of every pair starts from the same state; the seeds' starts differ.
    starts = {
        (p["observer"], p["controller"]): [e["start_distance_m"] for e in p["episodes"]]
        for p in results["pairs"]
    }
    first = starts["oracle", "lqr"]
    assert all(s == first for s in starts.values()) and len(set(first)) == len(SEEDS)
    assert results["starts_match"] is True
    for observer, controller in (("oracle", "lqr"), ("kf-measurements", "pid")):
        run = run_experiment(
            "BallTable-v0",
            observer,
            controller,
            len(SEEDS),
            SEEDS[0],
            tmp_path / f"{observer}-{controller}",
            steps=STEPS,
            progress=False,
        )
        compared_pair = pair(results, observer, controller)
        assert compared_pair["episodes"] == run["episodes"]
        assert compared_pair["summary"] == run["summary"]
        assert compared_pair["statistics"][PRIMARY]["mean"] == run["summary"][PRIMARY]


def test_the_oracle_column_is_the_paired_difference(compared):
    out_dir, _ = compared
    results = json.loads((out_dir / "results.json").read_text())
    text = (out_dir / "table.md").read_text()
    rows = {(r[0], r[1]): r for r in table_rows(text)[1:]}
    _, _, scale, digits, _ = COMPARE_METRICS[PRIMARY]
    for controller in CONTROLLERS:
        oracle = [e[PRIMARY] for e in pair(results, "oracle", controller)["episodes"]]
        observer = [e[PRIMARY] for e in pair(results, "kf-measurements", controller)["episodes"]]
        differences = np.subtract(observer, oracle)
        assert np.all(differences != 0.0)  # the observer does change the closed loop
        diff = pair(results, "kf-measurements", controller)["vs_oracle"]
        assert diff["n"] == len(SEEDS)
        assert diff["mean"] == pytest.approx(np.mean(differences), rel=1e-12)
        low, high = stats.t.interval(
            0.95, len(SEEDS) - 1, loc=np.mean(differences), scale=stats.sem(differences)
        )
        assert (diff["low"], diff["high"]) == pytest.approx((low, high), rel=1e-9)
        assert diff["ratio"] == pytest.approx(np.mean(observer) / np.mean(oracle), rel=1e-12)
        cell = rows["kf-measurements", controller][-2]
        assert cell.startswith(
            f"{diff['mean'] * scale:+.{digits}f} ± {diff['half_width'] * scale:.{digits}f} "
        )
        assert f"(×{diff['ratio']:.2f})" in cell
        # The paired interval is narrower than the unpaired one: the seeds' spread cancels.
        unpaired = math.hypot(
            pair(results, "oracle", controller)["statistics"][PRIMARY]["half_width"],
            pair(results, "kf-measurements", controller)["statistics"][PRIMARY]["half_width"],
        )
        assert diff["half_width"] < unpaired


@pytest.fixture
def no_plots(monkeypatch):
    """Skip drawing (most of a short comparison's time); the first test checks the plots."""
    monkeypatch.setattr(compare_report, "plot_bars", lambda *args, **kwargs: None)
    monkeypatch.setattr(ball_table, "plot", lambda records, observer, out_dir: [])


def without_files(pairs: list[dict]) -> list[dict]:
    return [{k: v for k, v in p.items() if k != "files"} for p in pairs]


@pytest.mark.slow  # spawned workers (27 s at load 7); test_outside_entries.py's twin stays
def test_two_workers_give_the_results_of_one(compared, tmp_path, no_plots):
    _, results = compared
    again = run_comparison(
        "BallTable-v0", OBSERVERS, CONTROLLERS, SEEDS, tmp_path, workers=2, steps=STEPS,
        progress=False, cli_args={"from": "test"},
    )  # fmt: skip
    assert without_files(again["pairs"]) == without_files(results["pairs"])
    assert again["config"]["workers"] == 2


@pytest.mark.slow  # starts Ray (43 s at load 7)
def test_the_ray_backend_gives_the_local_results(tmp_path, no_plots):
    pytest.importorskip("ray")
    args = ("BallTable-v0", OBSERVERS, ["lqr"], [0, 1])
    local = run_comparison(*args, tmp_path / "local", steps=40, progress=False)
    remote = run_comparison(*args, tmp_path / "ray", steps=40, progress=False, backend="ray")
    assert remote["pairs"] == local["pairs"]
    assert remote["config"]["backend"] == "ray" and "ray" in remote["versions"]
    tables = [(tmp_path / b / "table.md").read_text().split("\n\n")[1] for b in ("ray", "local")]
    assert tables[0] == tables[1]


def test_without_ray_the_ray_backend_says_how_to_install_it(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray now raises ImportError
    with pytest.raises(ImportError, match=r"pip install 'observer-gym\[distributed\]'"):
        ray_backend.run_episodes_ray([])
    monkeypatch.setattr(request.importlib.util, "find_spec", lambda name: None)
    with pytest.raises(ValueError, match=r"needs Ray.*pip install 'observer-gym\[distributed\]'"):
        run_comparison("BallTable-v0", ["oracle"], ["lqr"], [0], tmp_path / "out", backend="ray")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        (
            {"observers": ["oracle", "kf-magic"]},
            "unknown observer 'kf-magic' for .*allowed: oracle",
        ),
        ({"controllers": ["lqr", "lqg"]}, "unknown controller 'lqg'; allowed: lqr"),
        ({"observers": ["oracle", "kf", "oracle"]}, "observers lists 'oracle' more than once"),
        ({"controllers": ["pid", "pid"]}, "controllers lists 'pid' more than once"),
        ({"controllers": []}, "controllers must name at least one"),
        ({"observers": []}, "observers must name at least one"),
        ({"seeds": []}, "seeds must hold at least one seed"),
        ({"seeds": [1, 2, 1]}, r"seeds must be distinct; \[1\] appear"),
        ({"seeds": [-1]}, "seeds must be integers >= 0, got -1"),
        ({"address": "auto"}, "address 'auto' .* needs backend 'ray', got 'local'"),
        ({"backend": "dask"}, "unknown backend 'dask'; allowed: local, ray"),
        ({"backend": "ray", "workers": 2}, "workers=2 applies to the local backend only"),
        ({"steps": 0}, "steps must be an integer >= 1"),
        ({"env_kwargs": {"obs_mode": "rgb"}}, "must not set obs_mode"),
        ({"env_id": "BallPool-v0"}, "unknown env 'BallPool-v0'"),
    ],
)
def test_bad_input_is_refused_before_any_env_is_built(changes, message, tmp_path, monkeypatch):
    def no_env(*args, **kwargs):
        raise AssertionError("an env was built for a bad input")

    monkeypatch.setattr(gymnasium, "make", no_env)
    inputs = {
        "env_id": "BallTable-v0",
        "observers": ["oracle", "kf"],
        "controllers": ["lqr"],
        "seeds": [0, 1],
        **changes,
    }
    with pytest.raises(ValueError, match=message):
        run_comparison(**inputs, out_dir=tmp_path / "out", progress=False)
    assert not (tmp_path / "out").exists()


def test_a_controller_of_another_env_is_refused_before_running(tmp_path):
    with pytest.raises(ValueError, match=r"controller 'intercept' does not fit .*BallTable"):
        run_comparison("BallTable-v0", ["oracle"], ["lqr", "intercept"], [0], tmp_path / "out")
    assert not (tmp_path / "out").exists()


# --- statistics --------------------------------------------------------------------------
def test_mean_interval_is_students_t():
    # mean 3, s = sqrt(2.5), t_{0.975, 4} = 2.776445 (tables): 2.776445 * sqrt(2.5 / 5)
    result = mean_interval([1.0, 2.0, None, 3.0, 4.0, 5.0])
    assert result["n"] == 5 and result["mean"] == 3.0
    assert result["half_width"] == pytest.approx(2.776445 * math.sqrt(0.5), rel=1e-6)
    assert (result["low"], result["high"]) == pytest.approx(
        stats.t.interval(0.95, 4, loc=3.0, scale=stats.sem([1, 2, 3, 4, 5])), rel=1e-12
    )
    assert mean_interval([2.0])["half_width"] is None and mean_interval([2.0])["mean"] == 2.0
    assert mean_interval([None, None]) == {
        "n": 0, "mean": None, "half_width": None, "low": None, "high": None, "method": "student-t"
    }  # fmt: skip


def test_rate_interval_is_wilsons():
    caught = [True] * 7 + [False] * 3 + [None]
    result = rate_interval(caught)
    # Wilson score interval by hand: (p + z²/2n ± z sqrt(p(1-p)/n + z²/4n²)) / (1 + z²/n)
    n, p, z = 10, 0.7, stats.norm.ppf(0.975)
    centre = (p + z**2 / (2 * n)) / (1 + z**2 / n)
    half = z * math.sqrt(p * (1 - p) / n + z**2 / (4 * n**2)) / (1 + z**2 / n)
    assert result["n"] == 10 and result["mean"] == 0.7
    assert (result["low"], result["high"]) == pytest.approx((centre - half, centre + half))
    assert (result["low"], result["high"]) == pytest.approx((0.3968, 0.8922), abs=1e-4)
    assert metric_statistics(caught)["method"] == "wilson"
    assert metric_statistics([0.1, 0.2])["method"] == "student-t"


def test_paired_difference_of_rates_and_skipped_episodes():
    diff = paired_difference([True, False, True, None], [True, True, True, True])
    assert diff["n"] == 3 and diff["mean"] == pytest.approx(-1 / 3)
    assert diff["ratio"] == pytest.approx(2 / 3)
    assert paired_difference([1.0, 2.0], [0.0, 0.0])["ratio"] is None
    with pytest.raises(ValueError, match="differ in length"):
        paired_difference([1.0], [1.0, 2.0])


# --- names and the command line ----------------------------------------------------------
def test_folder_names_are_safe_and_distinct():
    assert safe_name("ppo:runs/ppo-balltable") == "ppo-runs-ppo-balltable"
    assert pair_folders([("kf", "ppo:runs/x"), ("kf", "ppo:runs_x"), ("kf", "ppo:runs:x")]) == [
        "kf__ppo-runs-x",
        "kf__ppo-runs_x",
        "kf__ppo-runs-x-2",
    ]


def test_seed_lists_parse_and_print_as_ranges():
    assert compare_cli.seed_list("0-4,10,12-13") == [0, 1, 2, 3, 4, 10, 12, 13]
    assert format_seeds([0, 1, 2, 3, 4, 10, 12, 13]) == "0-4,10,12-13"
    for bad in ("3-1", "a", "1,,2", "-2"):
        with pytest.raises(argparse.ArgumentTypeError):
            compare_cli.seed_list(bad)


def test_the_command_line_reads_back_its_env_options():
    env_kwargs = {"camera_preset": "single", "latency_s": 0.02, "label": "1", "on": True}
    line = command_line("observer_gym/BallCatcher-v1", ["oracle"], ["intercept"], [0], None, 1,
                        "local", None, env_kwargs)  # fmt: skip
    words = shlex.split(line)
    options = [env_option(words[i + 1]) for i, w in enumerate(words) if w == "--env-option"]
    assert dict(options) == env_kwargs


def parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="observer-gym compare")
    compare_cli.add_arguments(parser)
    return parser


# the benchmark's lab level: kf-measurements with intercept misses most throws
LAB = load_suite("BallCatcher-v1", "v1").level("lab").env_options


def check_miss_counts(results: dict, text: str) -> None:
    """The BallCatcher table's counted column: right after the catch rate, each pair's
    episodes not caught counted by their reason, as results.json holds them."""
    reasons = list(ball_catcher.NOT_CAUGHT_REASONS)
    assert results["config"]["counts"] == {
        "miss_reason": {"label": "misses by reason", "values": reasons}
    }
    header, *rows = table_rows(text)
    assert header[2].startswith("catch rate") and header[3] == "misses by reason"
    for row in rows:
        found = pair(results, row[0], row[1])
        episodes = found["episodes"]
        for e in episodes:
            assert (e["miss_reason"] is None) == e["caught"]
        counts = found["counts"]["miss_reason"]
        assert counts == {r: sum(e["miss_reason"] == r for e in episodes) for r in reasons}
        assert counts == found["summary"]["miss_reasons"]
        assert sum(counts.values()) == len(episodes) - sum(e["caught"] for e in episodes)
        shown = ", ".join(f"{r} {k}" for r, k in counts.items() if k) or "none"
        assert row[3] == shown


def test_ball_catchers_table_counts_the_misses_by_reason(tmp_path, monkeypatch):
    monkeypatch.setattr(compare_report, "plot_bars", lambda *args, **kwargs: None)
    monkeypatch.setattr(ball_catcher, "plot", lambda records, observer, out_dir: [])
    args = ("BallCatcher-v1", ["oracle", "kf-measurements"], ["intercept"])
    results = run_comparison(
        *args, [5000, 5001, 5002], tmp_path / "lab", env_kwargs=LAB, progress=False
    )
    assert json.loads((tmp_path / "lab" / "results.json").read_text()) == results
    check_miss_counts(results, (tmp_path / "lab" / "table.md").read_text())
    check_miss_counts(results, compare_report.comparison_text(results))
    assert {e["miss_reason"] for p in results["pairs"] for e in p["episodes"]} <= {
        None,
        *MISS_REASONS,
    }
    # Cut at 0.1 s, long before the ball reaches the box (0.40-0.48 s): every episode is
    # unfinished, none a catch.
    cut = run_comparison(*args, [0, 1], tmp_path / "cut", steps=10, progress=False)
    check_miss_counts(cut, (tmp_path / "cut" / "table.md").read_text())
    assert [p["counts"]["miss_reason"]["unfinished"] for p in cut["pairs"]] == [2, 2]


def test_a_task_without_counted_columns_keeps_its_results(compared):
    _, results = compared
    assert "counts" not in results["config"]
    assert all("counts" not in p for p in results["pairs"])


def test_cli_runs_a_comparison_that_its_command_line_repeats(tmp_path):
    argv = ["--observers", "oracle,kf-measurements", "--controllers", "lqr", "--seeds", "2,5"]
    argv += ["--steps", "30", "--out", str(tmp_path), "--no-progress"]
    assert compare_cli.run(parser().parse_args(argv)) == 0
    results = json.loads((tmp_path / "results.json").read_text())
    assert results["config"]["seeds"] == [2, 5] and results["config"]["steps"] == 30
    assert results["config"]["cli_args"]["out"] == str(tmp_path)
    command = (tmp_path / "table.md").read_text().splitlines()[0].strip("`")
    words = shlex.split(command)
    assert words[:2] == ["observer-gym", "compare"]
    again = parser().parse_args(words[2:])
    assert (again.env, again.observers, again.controllers, again.seeds, again.steps) == (
        "observer_gym/BallTable-v0",
        ["oracle", "kf-measurements"],
        ["lqr"],
        [2, 5],
        30,
    )


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--seeds", "0-3", "--episodes", "4"], "--seeds lists the seeds: give it alone"),
        (["--seeds", "0-3", "--seed", "1"], "--seeds lists the seeds: give it alone"),
        (["--address", "auto"], "needs backend 'ray'"),
    ],
)
def test_cli_refuses_conflicting_options(argv, message, tmp_path, capsys):
    base = ["--observers", "oracle", "--controllers", "lqr", "--out", str(tmp_path / "out")]
    assert compare_cli.run(parser().parse_args(base + argv)) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_cli_episodes_and_seed_make_consecutive_seeds(tmp_path, monkeypatch):
    seen = {}
    monkeypatch.setattr(
        "observer_gym.train.experiments.api.compare",
        lambda *args, **kwargs: seen.update(kwargs) or SimpleNamespace(text="(not run)"),
    )
    argv = ["--observers", "oracle", "--controllers", "pid", "--episodes", "3", "--seed", "7"]
    assert compare_cli.run(parser().parse_args([*argv, "--out", str(tmp_path)])) == 0
    assert seen["seeds"] == [7, 8, 9] and seen["backend"] == "local"
    assert compare_cli.run(parser().parse_args([*argv[:4], "--out", str(tmp_path)])) == 0
    assert seen["seeds"] == list(range(10))
