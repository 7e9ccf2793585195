"""A training run's folder corrupted at random: checkpoint files, their records
(latest.json, checkpoint_<N>.json) and config.json cut, overwritten with junk bytes or
junk JSON, bytes flipped, or deleted. What ``train --resume`` reads either refuses with a
ValueError or gives exactly what the run saved: the checkpoint it picks is one of the
run's sets, each file byte for byte as saved, and the config the one written."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from fuzzlib import record
from hypothesis import given, note
from hypothesis import strategies as st

from observer_gym.train.rl.run_dir import check_resumable, intact_checkpoint, read_config

STEPS = 64  # tests/conftest.py's tiny_run: a checkpoint every 64 env steps
FILES = [
    "config.json",
    "checkpoints/latest.json",
    "checkpoints/checkpoint_64.json",
    "checkpoints/checkpoint_128.json",
    "checkpoints/model_64.zip",
    "checkpoints/model_128.zip",
    "checkpoints/vecnormalize_64.npz",
    "checkpoints/vecnormalize_128.npz",
]


@pytest.fixture(scope="module")
def saved(tiny_run) -> Path:
    """tests/conftest.py's finished 128-step PPO run: checkpoints at 64 and 128 steps."""
    assert set(FILES) <= {p.relative_to(tiny_run).as_posix() for p in tiny_run.rglob("*.*")}
    return tiny_run


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=8), inner),
    max_leaves=8,
)
CHECKPOINT_KEYS = st.sampled_from(["timesteps", "model", "vecnormalize", "sha256", "x"])


@st.composite
def corruptions(draw) -> tuple[str, str, object]:
    """(file, how, argument): a file of the run and what is done to it."""
    name = draw(st.sampled_from(FILES))
    hows = ["cut", "flip", "bytes", "json", "delete"] + (["edit"] if name.endswith(".json") else [])
    how = draw(st.sampled_from(hows))
    if how == "cut":
        return name, how, draw(st.floats(0.0, 1.0, exclude_max=True))
    if how == "flip":
        return name, how, draw(st.lists(st.floats(0.0, 1.0, exclude_max=True), min_size=1))
    if how == "bytes":
        return name, how, draw(st.binary(max_size=64))
    if how == "json":
        return name, how, draw(json_values)
    if how == "edit":  # one key of a JSON file changed
        keys = CHECKPOINT_KEYS if "/" in name else st.text(max_size=8)
        return name, how, (draw(keys | st.sampled_from(["algo", "env_kwargs"])), draw(json_values))
    return name, how, None


def _corrupt(path: Path, how: str, argument) -> None:
    data = path.read_bytes()
    if how == "cut":
        path.write_bytes(data[: int(argument * len(data))])
    elif how == "flip" and data:
        changed = bytearray(data)
        for where in argument:
            changed[int(where * len(changed))] ^= 0xFF
        path.write_bytes(bytes(changed))
    elif how == "bytes":
        path.write_bytes(argument)
    elif how == "json":
        path.write_text(json.dumps(argument))
    elif how == "edit":
        try:
            content = json.loads(data)
        except ValueError:  # no longer JSON (an earlier harm)
            return
        key, value = argument
        if isinstance(content, dict):
            content[key] = value
        path.write_text(json.dumps(content))
    elif how == "delete":
        path.unlink()


@given(st.lists(corruptions(), min_size=1, max_size=3))
def test_resume_reads_what_was_saved_or_refuses(saved, tmp_path_factory, harms):
    run = Path(shutil.copytree(saved, tmp_path_factory.mktemp("corrupt") / "run"))
    for name, how, argument in harms:
        note(f"{how} {name}: {argument!r}")
        if (run / name).exists():
            _corrupt(run / name, how, argument)
    names = {name for name, _, _ in harms}
    category = "run folder: " + ("config.json" if "config.json" in names else "checkpoints")
    try:
        check_resumable(run)
    except ValueError as error:
        note(f"ValueError: {error}")
        record(category, accepted=False)
        if "config.json" not in names:  # the config is read first; else no intact checkpoint
            assert "intact checkpoint" in str(error)
            assert intact_checkpoint(run / "checkpoints")[0] is None
        return
    record(category, accepted=True)
    assert read_config(run) == read_config(saved)
    checkpoint, _ = intact_checkpoint(run / "checkpoints")
    assert checkpoint["timesteps"] in (STEPS, 2 * STEPS)
    for key, path in checkpoint.items():
        if key != "timesteps":
            assert path.read_bytes() == (saved / "checkpoints" / path.name).read_bytes()
