"""A toy random-delay study extended by BallTable's pixel input (slow: real trainings):
the same command with ``pixels`` added trains only the pixel agents, at the moderate
level only, evaluates them at every level, keeps the first study's records byte for byte
and re-derives its table (--check)."""

from __future__ import annotations

import pytest

from observer_gym.envs.json_file import read_json
from observer_gym.train.cli import main

pytestmark = [pytest.mark.slow, pytest.mark.timeout(1800)]

ARGS = [
    "study",
    "delay-rl",
    "--env",
    "BallTable-v0",
    "--levels",
    "none,moderate",
    "--seeds",
    "0",
    "--timesteps",
    "2048",
    "--eval-episodes",
    "1",
    "--no-progress",
]


def test_adding_pixels_to_a_finished_study_trains_them_at_moderate_only(tmp_path, capsys):
    out = tmp_path / "study"
    assert main([*ARGS, "--inputs", "truth", "--out", str(out)]) == 0
    first = {p: p.read_bytes() for p in (out / "eval").rglob("*.json")}
    assert len(first) == 2  # the truth, trained once, at both levels
    capsys.readouterr()

    assert main([*ARGS, "--inputs", "truth,pixels", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    # one seed run (pixels at moderate), evaluated at both levels
    assert "1 seed runs trained, 2 evaluations" in printed
    assert sorted(p.name for p in (out / "train").iterdir()) == ["moderate", "none"]
    assert [p.name for p in (out / "train" / "moderate").iterdir()] == ["pixels"]
    assert {p: p.read_bytes() for p in first} == first  # the first study's records stay
    plan = read_json(out / "study.json")
    assert plan["inputs"] == ["truth", "pixels"]
    assert [a["inputs"] for a in plan["inputs_added"]] == [["pixels"]]

    table = read_json(out / "table.json")
    cells = {(c["trained_at"], c["input"], c["at"]) for c in table["cells"]}
    assert {c for c in cells if c[1] == "pixels"} == {
        ("moderate", "pixels", "none"),
        ("moderate", "pixels", "moderate"),
    }
    assert table["budget"]["seed_runs"] == 2
    text = (out / "table.md").read_text()
    row = next(line for line in text.splitlines() if line.startswith("| pixels: "))
    assert row.split("|")[2].strip() == "not trained (moderate only)"
    assert "not trained there)" in text  # the shift row's cell at none
    assert main(["study", "delay-rl", "--check", str(out)]) == 0

    # the first command again (fewer inputs than the folder's study) is refused
    capsys.readouterr()
    assert main([*ARGS, "--inputs", "truth", "--out", str(out)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and "holds another study" in err[0], err
