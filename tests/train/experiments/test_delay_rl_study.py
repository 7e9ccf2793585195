"""The whole random-delay study at toy size (slow: real trainings): it runs, continues
without redoing anything, re-derives its table from its per-seed records (--check), and
refuses another plan in its folder."""

from __future__ import annotations

import json

import numpy as np
import pytest

from observer_gym.envs.json_file import read_json
from observer_gym.train.cli import main

pytestmark = [pytest.mark.slow, pytest.mark.timeout(1800)]  # the toy study: 8 min at load 7

ARGS = [
    "study",
    "delay-rl",
    "--env",
    "BallTable-v0",
    "--levels",
    "none,moderate",
    "--inputs",
    "newest,truth",
    "--seeds",
    "0,1",
    "--timesteps",
    "2048",
    "--eval-episodes",
    "2",
    "--no-progress",
]


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    out = tmp_path_factory.mktemp("delay-rl") / "study"
    assert main([*ARGS, "--out", str(out)]) == 0
    return out


def test_the_table_is_the_records_statistics(study):
    table = read_json(study / "table.json")
    cells = {(c["trained_at"], c["input"], c["at"]): c for c in table["cells"]}
    assert set(cells) == {
        ("none", "newest", "none"),
        ("moderate", "newest", "none"),
        ("moderate", "newest", "moderate"),
        ("none", "truth", "none"),
        ("none", "truth", "moderate"),
    }
    for (trained_at, name, at), cell in cells.items():
        record = read_json(study / "eval" / trained_at / name / f"at_{at}.json")
        scores = [record["per_seed"][str(s)]["metric_mean"] for s in (0, 1)]
        for seed in ("0", "1"):  # a seed's score is the mean over its episodes
            entry = record["per_seed"][seed]
            assert entry["metric_mean"] == pytest.approx(np.mean(entry["metric"]))
            assert len(entry["metric"]) == 2
        # with two seeds the IQM trims nothing: the mean
        assert cell["metric"]["iqm"] == pytest.approx(np.mean(scores))
    # the state agent does not see the cameras: the same episodes at either level
    assert (
        cells[("none", "truth", "none")]["metric"]["scores"]
        == cells[("none", "truth", "moderate")]["metric"]["scores"]
    )
    delivery = table["delivery"]
    assert delivery["none"]["out_of_order_fraction"] == 0.0
    assert delivery["moderate"]["newest_age_mean_s"] > 0.04  # the latency, plus the jitter
    assert table["budget"]["seed_runs"] == 6  # newest at 2 levels, the truth once, 2 seeds
    assert (study / "curves_moderate.png").is_file()
    assert "## Shift: trained at moderate" in (study / "table.md").read_text()


def test_the_same_command_again_continues_and_redoes_nothing(study, capsys):
    before = (study / "table.json").read_text()
    capsys.readouterr()
    assert main([*ARGS, "--out", str(study)]) == 0
    assert "0 seed runs trained, 0 evaluations" in capsys.readouterr().out
    after = read_json(study / "table.json")
    assert after["cells"] == json.loads(before)["cells"]


def test_a_lost_evaluation_is_run_again_to_the_same_numbers(study):
    path = study / "eval" / "moderate" / "newest" / "at_none.json"
    kept = read_json(path)
    path.unlink()
    assert main([*ARGS, "--out", str(study)]) == 0
    assert read_json(path) == kept


def test_check_passes_then_names_a_changed_record(study, capsys):
    assert main(["study", "delay-rl", "--check", str(study)]) == 0
    path = study / "eval" / "none" / "newest" / "at_none.json"
    record = read_json(path)
    original = path.read_text()
    record["per_seed"]["1"]["metric_mean"] += 0.01
    path.write_text(json.dumps(record))
    try:
        capsys.readouterr()
        assert main(["study", "delay-rl", "--check", str(study)]) == 1
        err = capsys.readouterr().err.splitlines()
        assert len(err) == 1 and "cells differs" in err[0], err
    finally:
        path.write_text(original)


def test_another_plan_in_the_folder_is_refused_in_one_line(study, capsys):
    capsys.readouterr()
    argv = [*ARGS, "--out", str(study)]
    argv[argv.index("2048")] = "4096"
    assert main(argv) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and "holds another study" in err[0], err


def test_the_ray_backend_records_what_the_local_one_did(study, tmp_path):
    """The same seed runs trained as Ray tasks (a local Ray started by the command) are
    evaluated to the local study's per-seed records, bit for bit."""
    pytest.importorskip("ray")
    argv = [*ARGS, "--out", str(tmp_path / "ray"), "--backend", "ray"]
    argv[argv.index("none,moderate")] = "none"
    argv[argv.index("newest,truth")] = "truth"
    assert main(argv) == 0
    path = ("eval", "none", "truth", "at_none.json")
    assert (
        read_json(tmp_path.joinpath("ray", *path))["per_seed"]
        == (read_json(study.joinpath(*path))["per_seed"])
    )
