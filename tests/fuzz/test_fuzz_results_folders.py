"""Received folders tampered with at random: a published benchmark folder whose
scores.json gets a key twice, nesting past Python's parser, NaN or junk, whose files
become links to ``/dev/zero`` or to other files; and a training run whose files become
links to files outside it.

What is checked: ``benchmark --check`` (:func:`check_folder`) refuses every tampered
results folder with one line (a :class:`FolderCheckError`), never a RecursionError or
MemoryError, and writes nothing; the strict JSON reader refuses what it must; and what a
resumed run writes (the lock, eval.csv, monitor/, state.json, checkpoints' records)
replaces a link in its folder and never writes through it: the files outside stay byte
for byte."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest
from fuzzlib import record
from hypothesis import given, note, settings
from hypothesis import strategies as st

from observer_gym.envs.json_file import JSONFileError, parse_json
from observer_gym.train.cli import main
from observer_gym.train.experiments.benchmark.check import FolderCheckError, check_folder
from observer_gym.train.reports.folder_lock import LOCK_FILE, folder_lock
from observer_gym.train.reports.outputs import write_json_atomic
from observer_gym.train.rl.learning import append_eval_row, replace_links
from observer_gym.train.rl.run_dir import read_config, read_state

REPO = Path(__file__).resolve().parents[2]
ROOT = REPO / "docs" / "results" / "benchmark" / "v1"
SMALLEST = min((p.parent for p in ROOT.glob("*/*/scores.json")), key=lambda p: p.stat().st_size)

json_values = st.recursive(
    st.none()
    | st.booleans()
    | st.integers()
    | st.floats(allow_nan=False, allow_infinity=False)
    | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=8), inner),
    max_leaves=8,
)
SCORES_KEYS = ["aggregate", "levels", "suite", "env", "observer", "controller", "official"]


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {
        p.relative_to(folder).as_posix(): p.read_bytes()
        for p in folder.rglob("*")
        if p.is_file() and not p.is_symlink()
    }


@st.composite
def tampers(draw) -> tuple[str, str, object]:
    """(file, how, argument) for a published benchmark folder."""
    name = draw(st.sampled_from(["scores.json", "episodes.csv", "table.md"]))
    hows = ["zero", "bytes", "link"]
    if name == "scores.json":
        hows += ["twice", "deep", "nan", "json"]
    how = draw(st.sampled_from(hows))
    if how == "twice":  # a key written again, first or last, with another value
        return (
            name,
            how,
            (draw(st.sampled_from(SCORES_KEYS)), draw(json_values), draw(st.booleans())),
        )
    if how == "deep":
        return name, how, draw(st.integers(65, 300_000))
    if how == "nan":
        return name, how, draw(st.sampled_from(["aggregate", "episodes_per_level"]))
    if how == "json":
        return name, how, draw(json_values)
    if how == "bytes":
        return name, how, draw(st.binary(max_size=64))
    if how == "link":  # to another file of the folder
        return name, how, draw(st.sampled_from(["scores.json", "episodes.csv", "table.md"]))
    return name, how, None  # "zero": a link to /dev/zero


def _tamper(folder: Path, name: str, how: str, argument) -> None:
    path = folder / name
    readable = path.is_file() and not path.is_symlink()
    text = path.read_text(encoding="utf-8", errors="replace") if readable else "{}"
    if how == "twice":  # the key again, before or after the others, with another value
        key, value, first = argument
        pair = f"{json.dumps(key)}: {json.dumps(value)}"
        body = text.strip()
        inner = body[1:-1].strip() if body.startswith("{") and body.endswith("}") else ""
        pairs = [pair] if f"{json.dumps(key)}:" in inner else [pair, pair]
        parts = [*pairs, inner] if first else [inner, *pairs]
        path.write_text("{" + ", ".join(part for part in parts if part) + "}")
    elif how == "deep":
        path.write_text("[" * argument + "]" * argument)
    elif how == "nan":
        doc = json.loads(text) if text.strip().startswith("{") else {}
        doc[argument] = float("nan")
        path.write_text(json.dumps(doc))  # Python writes NaN
    elif how == "json":
        path.write_text(json.dumps(argument))
    elif how == "bytes":
        path.write_bytes(argument)
    elif how in ("zero", "link"):
        path.unlink(missing_ok=True)
        if how == "zero":
            path.symlink_to("/dev/zero")
        elif argument != name:
            path.symlink_to(folder / argument)
        else:
            path.symlink_to(folder / "missing")  # a link to itself would loop: a dangling one


@settings(max_examples=max(5, settings().max_examples // 4))
@given(st.lists(tampers(), min_size=1, max_size=3))
@pytest.mark.timeout(120)
def test_check_refuses_a_tampered_results_folder_in_one_line(tmp_path_factory, harms):
    folder = tmp_path_factory.mktemp("tampered") / SMALLEST.name
    shutil.copytree(SMALLEST, folder)
    for name, how, argument in harms:
        note(f"{how} {name}: {str(argument)[:80]!r}")
        _tamper(folder, name, how, argument)
    before = _snapshot(folder)
    category = "results folder: " + ",".join(sorted({how for _, how, _ in harms}))
    try:
        check_folder(folder, same_packages=False)
    except FolderCheckError as error:
        record(category, accepted=False)
        assert "\n" not in str(error)
    else:  # every tamper above changes what the folder says: none may pass
        record(category, accepted=True)
        pytest.fail(f"{harms} passed the check")
    assert _snapshot(folder) == before  # a check writes nothing


@given(json_values, st.integers(0, 5), st.sampled_from(SCORES_KEYS))
def test_the_reader_refuses_a_key_twice_wherever_it_is(value, depth, key):
    """A key twice at any depth of an object: refused; the same text without the second
    key: read as json reads it."""
    once = {key: value}
    twice_text = f"{{{json.dumps(key)}: {json.dumps(value)}, {json.dumps(key)}: 0}}"
    for _ in range(depth):
        once = {"x": [once]}
        twice_text = f'{{"x": [{twice_text}]}}'
    assert parse_json(json.dumps(once), "once.json") == once
    with pytest.raises(JSONFileError, match="appears twice"):
        parse_json(twice_text, "twice.json")
    record("json: a key twice", accepted=False)


# --- links in a training run's folder ---------------------------------------------------------
STEPS = 64  # tests/conftest.py's tiny_run: a checkpoint every 64 env steps
LINKABLE = [
    LOCK_FILE,
    "eval.csv",
    "state.json",
    "config.json",
    "monitor/0.monitor.csv",
    "monitor",
    "logs",
    "checkpoints/latest.json",
]


@pytest.fixture(scope="module")
def saved(tiny_run) -> Path:
    """tests/conftest.py's finished 128-step PPO run: checkpoints at 64 and 128 steps."""
    return tiny_run


def _link_out(run: Path, outside: Path, names: list[str]) -> None:
    """Make each of ``names`` in ``run`` a link to a copy of it in ``outside`` (a file or
    folder that was not there: a link to a new file outside)."""
    for name in names:
        path = run / name
        target = outside / name.replace("/", "__")
        if path.is_symlink():
            continue
        if path.is_dir():
            shutil.copytree(path, target)
            shutil.rmtree(path)
        elif path.is_file():
            shutil.copyfile(path, target)
            path.unlink()
        else:
            target.write_text("outside\n")
        path.parent.mkdir(parents=True, exist_ok=True)
        path.symlink_to(target)


@settings(max_examples=max(5, settings().max_examples // 2))
@given(st.lists(st.sampled_from(LINKABLE), min_size=1, max_size=4, unique=True))
def test_what_a_resume_writes_never_goes_through_a_link(saved, tmp_path_factory, names):
    """The writes a resume makes before and after training, without the training: the
    lock, replace_links, the evaluation row, state.json and a checkpoint record."""
    base = tmp_path_factory.mktemp("links")
    run, outside = base / "run", base / "outside"
    shutil.copytree(saved, run)
    outside.mkdir()
    _link_out(run, outside, names)
    before = _snapshot(outside)
    note(f"links: {names}")
    try:
        with folder_lock(run, "train --resume"):
            read_config(run)  # reading through a link is allowed
            read_state(run)
            replace_links(run)
            append_eval_row(run / "eval.csv", [192, 1.0, 0.0, 0.0, 1.0, 1])
            write_json_atomic(run / "state.json", {"status": "finished"})
            write_json_atomic(run / "checkpoints" / "latest.json", {"timesteps": 0})
    except OSError as error:
        record("run folder: links", accepted=False)
        assert LOCK_FILE in names and "symbolic link" in str(error)
    else:
        record("run folder: links", accepted=True)
        assert LOCK_FILE not in names
        for name in ("eval.csv", "state.json", "checkpoints/latest.json"):
            assert not (run / name).is_symlink(), name
        assert not (run / "monitor").is_symlink() and not (run / "logs").is_symlink()
    assert _snapshot(outside) == before


@pytest.mark.slow
@settings(max_examples=max(3, settings().max_examples // 10))
@given(st.lists(st.sampled_from(LINKABLE[1:]), min_size=1, max_size=4, unique=True))
def test_a_resumed_training_never_writes_through_a_link(saved, tmp_path_factory, names):
    """The whole ``train --resume`` (64 more steps) with links in the run's folder."""
    base = tmp_path_factory.mktemp("links_cli")
    run, outside = base / "run", base / "outside"
    shutil.copytree(saved, run)
    outside.mkdir()
    _link_out(run, outside, names)
    before = _snapshot(outside)
    note(f"links: {names}")
    code = main(["train", "--no-progress", "--timesteps", str(3 * STEPS), "--resume", str(run)])
    record("run folder: links, resumed", accepted=code == 0)
    assert code in (0, 2)  # 2: a linked latest.json's copy is read and checked as any
    assert _snapshot(outside) == before
    if code == 0:
        assert not any(
            (run / name).is_symlink() for name in ("eval.csv", "state.json", "monitor", "logs")
        )
    assert os.path.isdir(run / "checkpoints")
