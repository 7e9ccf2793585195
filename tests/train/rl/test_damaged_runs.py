"""A training run's folder damaged after it was written: a damaged or missing checkpoint
file, a damaged latest.json, an edited config.json. ``train --resume`` falls back to the
newest intact checkpoint with a one-line warning, or stops with one line; it never
trains from a file that is not what the run saved."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from observer_gym.train.cli import main
from observer_gym.train.rl import run_dir


@pytest.fixture
def run(tiny_run, tmp_path) -> Path:
    """A copy of the trained run to damage."""
    return Path(shutil.copytree(tiny_run, tmp_path / "run"))


def _truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def _flip_a_byte(path: Path) -> None:
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))


DAMAGED = "is damaged (not the file that was saved)"
DAMAGES = {
    "model truncated": ("model_128.zip", _truncate, DAMAGED),
    "model missing": ("model_128.zip", Path.unlink, "is missing"),
    "statistics flipped": ("vecnormalize_128.npz", _flip_a_byte, DAMAGED),
}


@pytest.mark.parametrize("damage", DAMAGES.values(), ids=DAMAGES.keys())
def test_the_newest_intact_checkpoint_is_chosen(run, damage):
    name, harm, says = damage
    checkpoints = run / "checkpoints"
    assert run_dir.intact_checkpoint(checkpoints) == (
        {
            "timesteps": 128,
            "model": checkpoints / "model_128.zip",
            "vecnormalize": checkpoints / "vecnormalize_128.npz",
        },
        [],
    )
    harm(checkpoints / name)
    checkpoint, problems = run_dir.intact_checkpoint(checkpoints)
    assert checkpoint["timesteps"] == 64
    assert problems == [f"{checkpoints / name} {says}"]


def test_resume_falls_back_to_the_checkpoint_before_a_damaged_one(run, capsys):
    """The newest model cut in half ('File is not a zip file' from SB3 before): the run
    resumes from the set before it, with a one-line warning, its count carried on."""
    _truncate(run / "checkpoints" / "model_128.zip")
    assert main(["train", "--resume", str(run), "--timesteps", "192", "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert err.splitlines() == [
        f"observer-gym train: warning: {run / 'checkpoints' / 'model_128.zip'} is damaged (not "
        "the file that was saved); resuming from the checkpoint at 64 steps"
    ]
    state = json.loads((run / "state.json").read_text())
    assert (state["status"], state["timesteps"], state["segment_steps"]) == ("finished", 192, 128)
    assert (run / "logs" / "resume-64" / "progress.csv").is_file()


def test_no_intact_checkpoint_is_one_line(run, capsys):
    """Both sets damaged, latest.json too: one line naming each, exit code 2."""
    checkpoints = run / "checkpoints"
    (checkpoints / "model_64.zip").unlink()
    _flip_a_byte(checkpoints / "vecnormalize_128.npz")
    (checkpoints / "latest.json").write_text("{")
    assert main(["train", "--resume", str(run), "--no-progress"]) == 2
    assert capsys.readouterr().err.splitlines() == [
        f"observer-gym train: error: {run} has no intact checkpoint to resume from: "
        f"{checkpoints / 'latest.json'} is damaged; {checkpoints / 'vecnormalize_128.npz'} is "
        f"damaged (not the file that was saved); {checkpoints / 'model_64.zip'} is missing"
    ]


@pytest.mark.parametrize(
    ("edit", "value"),
    [("algo", "sac"), ("env_kwargs", {"push_rate_hz": 2.0}), ("algo", "a2c")],
    ids=["algo", "env option", "unknown algo"],
)
def test_an_edited_config_is_refused(run, capsys, edit, value):
    """config.json edited after the run wrote it: the recorded sha256 no longer matches;
    resuming (or loading the agent) stops with one line instead of an AttributeError or
    training silently on other settings."""
    path = run / "config.json"
    config = json.loads(path.read_text())
    config[edit] = value
    path.write_text(json.dumps(config))
    with pytest.raises(ValueError, match=r"was changed after the run wrote it .*config_sha256"):
        run_dir.check_resumable(run)
    assert main(["train", "--resume", str(run), "--no-progress"]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith(f"observer-gym train: error: {path} was changed after the run")


def test_a_config_with_an_unknown_algo_is_refused(run):
    """A config.json whose hash matches but whose algo is none the package trains."""
    path = run / "config.json"
    config = json.loads(path.read_text())
    run_dir.write_config(run, {**config, "algo": "a2c"})
    with pytest.raises(ValueError, match="names algo 'a2c'; allowed: ppo, sac, td3"):
        run_dir.read_config(run)
