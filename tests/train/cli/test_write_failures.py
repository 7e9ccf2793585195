"""Outputs that cannot be written: a full disk (the file size limit, EFBIG) while ``run``
or ``compare`` writes, and a sweep whose cells hold a number JSON cannot hold. Each is
one ``error:`` line and exit code 1, and the folder keeps the outputs it had, byte for
byte: a report is written as a set or not at all, and no partial file (a cut plot) is
left."""

from __future__ import annotations

import json

import pytest
from run_folders import file_size_limit, snapshot

from observer_gym.train.cli import main
from observer_gym.train.experiments import sweep

FILE_SIZE_LIMIT_BYTES = 16_000  # a plot is larger; results.json and table.md are not


COMMANDS = {
    "run": ["run", "--observer", "oracle", "--controller", "lqr"],
    "compare": ["compare", "--observers", "oracle", "--controllers", "lqr"],
}


@pytest.mark.parametrize(  # compare (3 s at load ~2) takes run's writer: slow
    "command",
    [pytest.param(argv, id=name, marks=[pytest.mark.slow] if name == "compare" else [])
     for name, argv in COMMANDS.items()],
)  # fmt: skip
def test_a_full_disk_is_one_line_and_keeps_the_earlier_outputs(command, tmp_path, capsys):
    out = tmp_path / "out"
    argv = [*command, "--episodes", "1", "--steps", "5", "--out", str(out), "--no-progress"]
    assert main(argv) == 0
    before = snapshot(out)
    assert any(len(data) > FILE_SIZE_LIMIT_BYTES for name, data in before.items())
    argv[argv.index("--steps") + 1] = "6"  # other numbers: a new set of outputs
    capsys.readouterr()
    with file_size_limit(FILE_SIZE_LIMIT_BYTES):
        code = main(argv)
    assert code == 1
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith(f"observer-gym {command[0]}: error: could not write {out}/")
    assert line.endswith("File too large")
    assert snapshot(out) == before  # no partial plot, no new file beside the old ones


SWEEP = [
    "sweep", "--vary", "measurement_noise_px=0,2", "--observers", "oracle",
    "--controllers", "lqr", "--episodes", "2", "--steps", "5", "--no-progress",
]  # fmt: skip


@pytest.mark.parametrize("value", [float("nan"), "abc"], ids=["nan", "text"])
def test_a_cell_that_cannot_be_summarised_writes_nothing(value, tmp_path, capsys, monkeypatch):
    """A cell file whose metric is NaN (or text): before, the table, CSV and plot were
    rewritten and results.json then failed, the old one left beside them. Such a cell
    no longer passes the resume's check (its records do not match their sha256: it runs
    again, tests/train/experiments/test_sweep_cells.py); here it is let through that check, to reach
    the summary."""
    out = tmp_path / "sweep"
    assert main([*SWEEP, "--out", str(out)]) == 0
    (cell,) = (out / "cells").glob("measurement_noise_px-2.0__*.json")
    data = json.loads(cell.read_text())
    data["episodes"][0]["mean_distance_m"] = value
    cell.write_text(json.dumps(data))
    before = snapshot(out)
    capsys.readouterr()
    monkeypatch.setattr(
        sweep,
        "finished_cells",
        lambda out_dir, plan: {
            path.stem: json.loads(path.read_text()) for path in (out_dir / "cells").glob("*.json")
        },
    )
    assert main([*SWEEP, "--out", str(out)]) == 1
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith("observer-gym sweep: error: ")
    assert "mean_distance_m" in line or "'abc'" in line
    assert snapshot(out) == before


def test_a_checkpoint_that_cannot_be_written_is_one_line(tmp_path, capsys):
    """A full disk at the first checkpoint (PyTorch's zip writer says 'unexpected pos'):
    one line naming the file, exit code 1, no partial checkpoint and no temp."""
    out = tmp_path / "run"
    argv = [
        "train", "--algo", "ppo", "--obs", "state", "--timesteps", "128", "--n-envs", "1",
        "--vec-env", "dummy", "--hyperparam", "n_steps=64", "--hyperparam", "batch_size=64",
        "--hyperparam", "checkpoint_freq=64", "--out", str(out), "--no-progress",
    ]  # fmt: skip
    with file_size_limit(FILE_SIZE_LIMIT_BYTES):
        code = main(argv)
    assert code == 1
    (line,) = capsys.readouterr().err.splitlines()
    model = out / "checkpoints" / "model_64.zip"
    assert line.startswith(f"observer-gym train: error: could not write {model}: ")
    # nothing in checkpoints/ (the run's output folder removes it too, being empty)
    assert list(out.glob("checkpoints/*")) == []


def test_an_output_folder_that_is_a_file_is_one_line(tmp_path, capsys):
    (tmp_path / "taken").write_text("")
    argv = [*COMMANDS["run"], "--episodes", "1", "--out", str(tmp_path / "taken")]
    assert main([*argv, "--no-progress"]) == 1
    assert capsys.readouterr().err.splitlines() == [
        f"observer-gym run: error: [Errno 17] File exists: '{tmp_path / 'taken'}'"
    ]
