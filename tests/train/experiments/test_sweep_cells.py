"""A resumed sweep reuses a cell file only if it is the plan's cell as written (issue
29, item 5): before, a cell was trusted on its format, the sweep's digest and its
episode count, so a cell file copied over another point's was reused (its row showing
the other point's numbers and "+0.00 (×1.00)"), and edited seeds or scaled metrics
passed. Now each such cell runs again, with a warning naming it and what differed, and
the outputs are those of an untouched sweep."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest

from observer_gym.train.cli import main
from observer_gym.train.experiments.sweep import SweepWarning, run_sweep

KEY = "measurement_noise_px"
ARGS = {"env_id": "BallTable-v0", "vary": {KEY: [0.0, 2.0]}, "observers": ["kf-measurements"],
        "controllers": ["lqr"], "episodes": 2, "seed": 3, "steps": 8,
        "progress": False}  # fmt: skip
ARGV = ["sweep", "--vary", f"{KEY}=0,2", "--observers", "kf-measurements", "--controllers",
        "lqr", "--episodes", "2", "--seed", "3", "--steps", "8", "--no-progress"]  # fmt: skip
OUTPUTS = ("results.json", "episodes.csv", "table.md")


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("sweep") / "out"
    run_sweep(**ARGS, out_dir=out)
    return out


def cell_paths(out: Path) -> tuple[Path, Path]:
    """The cells at the first and the second grid point."""
    (first,) = (out / "cells").glob(f"{KEY}-0.0__*.json")
    (second,) = (out / "cells").glob(f"{KEY}-2.0__*.json")
    return first, second


def edit(path: Path, change: Callable[[dict], None]) -> None:
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data, indent=2))


def copy_over(first: Path, second: Path) -> None:
    shutil.copyfile(first, second)


def seeds_changed(first: Path, second: Path) -> None:
    edit(second, lambda d: d["episodes"][1].update(seed=7))


def metrics_scaled(first: Path, second: Path) -> None:
    def scale(data: dict) -> None:
        for episode in data["episodes"]:
            episode["mean_distance_m"] *= 1.5

    edit(second, scale)


def summary_edited(first: Path, second: Path) -> None:
    edit(second, lambda d: d["summary"]["mean_distance_m"].update(mean=1.0))


def truncated(first: Path, second: Path) -> None:
    second.write_bytes(second.read_bytes()[:200])


def old_format(first: Path, second: Path) -> None:
    def downgrade(data: dict) -> None:
        data["format"] = 1
        del data["records_sha256"], data["summary"]

    edit(second, downgrade)


CASES = {
    "copied": (copy_over, rf"its id is \"{KEY}-0\.0__.*, not \"{KEY}-2\.0"),
    "seeds": (seeds_changed, r"its seeds are \[3,7\], not \[3,4\]"),
    "scaled": (metrics_scaled, "its records do not match the sha256 recorded with them"),
    "summary": (summary_edited, "its summary of mean_distance_m is not that of its episode"),
    "truncated": (truncated, "it is not readable as JSON"),
    "format-1": (old_format, "it is in cell format 1, not 2"),
}  # fmt: skip


@pytest.mark.parametrize("case", list(CASES))
def test_a_cell_that_is_not_the_plans_runs_again(case, reference, tmp_path):
    corrupt, why = CASES[case]
    out = tmp_path / "out"
    shutil.copytree(reference, out)
    first, second = cell_paths(out)
    corrupt(first, second)
    with pytest.warns(SweepWarning, match=rf"{second.stem}: {why}.*; it runs again"):
        result = run_sweep(**ARGS, out_dir=out)
    assert (result.cells_run, result.cells_reused) == (1, 1)
    for name in OUTPUTS:
        assert (out / name).read_bytes() == (reference / name).read_bytes(), name
    assert second.read_bytes() != b"" and json.loads(second.read_text())["id"] == second.stem


def test_an_intact_folder_is_reused_whole(reference, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(reference, out)
    result = run_sweep(**ARGS, out_dir=out)
    assert (result.cells_run, result.cells_reused) == (0, 2)


def test_the_command_says_which_cell_runs_again_in_one_line(reference, tmp_path, capsys):
    out = tmp_path / "out"
    shutil.copytree(reference, out)
    first, second = cell_paths(out)
    copy_over(first, second)
    assert main([*ARGV, "--out", str(out)]) == 0
    captured = capsys.readouterr()
    (line,) = [line for line in captured.err.splitlines() if second.stem in line]
    assert line.startswith("observer-gym sweep: warning: ")
    assert line.endswith("; it runs again")
    assert "1 cell(s) run, 1 reused" in captured.out
    assert "+0.00" not in (out / "table.md").read_text()  # not the first point's numbers
