"""A sweep's cell files corrupted at random before a resume: copied over another cell's,
seeds edited, metrics scaled, start states, ids, points or names changed, episodes
dropped or repeated, a key set to junk JSON, the file cut short or its bytes flipped.
:func:`~observer_gym.train.experiments.sweep_cells.finished_cells` reuses a file exactly
when it still holds what was written (the times, the JSON's layout and a newline may
differ), and otherwise leaves it out with a warning naming the cell (it runs again)."""

from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path

import pytest
from fuzzlib import record
from hypothesis import given, note
from hypothesis import strategies as st

from observer_gym.train.experiments.sweep import SweepWarning, finished_cells, run_sweep
from observer_gym.train.experiments.sweep_plan import check_sweep

KEY = "measurement_noise_px"
ARGS = {"env_id": "BallTable-v0", "vary": {KEY: [0.0, 2.0, 4.0]}, "observers": ["kf-measurements"],
        "controllers": ["lqr"], "episodes": 2, "seed": 1, "steps": 6}  # fmt: skip
UNCHECKED = ("timing",)  # wall-clock times: not part of what a cell says

json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=8), inner),
    max_leaves=6,
)


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    """A finished 3-cell sweep and its plan."""
    out = tmp_path_factory.mktemp("fuzz_sweep") / "out"
    run_sweep(**ARGS, out_dir=out, progress=False)
    plan = check_sweep(**ARGS)
    return out, plan


def _checked(data: dict) -> str:
    """What a cell says, as canonical JSON: everything but :data:`UNCHECKED`."""
    return json.dumps({k: v for k, v in data.items() if k not in UNCHECKED}, sort_keys=True)


def _scaled(data: dict, factor: float) -> None:
    for episode in data["episodes"]:
        for key, value in episode.items():
            if key not in ("episode", "seed") and isinstance(value, float):
                episode[key] = value * factor


def _edit(data: dict, how: str, draw) -> None:
    """Change ``data`` (a cell file's content) as ``how`` says."""
    if how == "seed":
        i = draw(st.integers(0, len(data["episodes"]) - 1))
        data["episodes"][i]["seed"] = draw(st.integers(0, 10**6))
    elif how == "scale":
        _scaled(data, draw(st.floats(0.01, 100.0).filter(lambda f: f != 1.0)))
    elif how == "metric":
        i = draw(st.integers(0, len(data["episodes"]) - 1))
        key = draw(st.sampled_from(sorted(data["episodes"][i])))
        data["episodes"][i][key] = draw(json_values)
    elif how == "start":
        i = draw(st.integers(0, len(data["starts"]) - 1))
        j = draw(st.integers(0, len(data["starts"][i]) - 1))
        data["starts"][i][j] = draw(st.floats(-1.0, 1.0))
    elif how == "identity":
        key = draw(st.sampled_from(["id", "point", "observer", "controller", "sweep", "format"]))
        data[key] = draw(json_values | st.just({KEY: 2.0}) | st.just("lqr"))
    elif how == "episodes":
        episodes = data["episodes"]
        data["episodes"] = draw(st.sampled_from([episodes[:1], episodes + episodes[:1],
                                                 episodes[::-1]]))  # fmt: skip
    elif how == "summary":
        metric = draw(st.sampled_from(sorted(data["summary"])))
        data["summary"][metric] = draw(json_values)
    elif how == "junk key":
        key = draw(st.sampled_from(sorted(data)))
        data[key] = draw(json_values)
    elif how == "timing":  # not a corruption: the times are not what the cell says
        data["timing"] = draw(json_values)


HOWS = ["copy", "cut", "flip", "seed", "scale", "metric", "start", "identity", "episodes",
        "summary", "junk key", "timing", "layout", "none"]  # fmt: skip


@given(st.data())
def test_a_cell_is_reused_exactly_when_it_holds_what_was_written(swept, tmp_path_factory, data):
    reference, plan = swept
    out = Path(shutil.copytree(reference, tmp_path_factory.mktemp("corrupt") / "out"))
    cells = sorted((out / "cells").glob("*.json"))
    target = data.draw(st.sampled_from(cells), label="cell")
    original = json.loads(target.read_text())
    how = data.draw(st.sampled_from(HOWS), label="how")
    text = target.read_text()
    if how == "copy":
        other = data.draw(st.sampled_from([c for c in cells if c != target]), label="from")
        text = other.read_text()
    elif how == "cut":
        text = text[: data.draw(st.integers(0, len(text) - 1), label="cut at")]
    elif how == "flip":
        raw = bytearray(text.encode())
        raw[data.draw(st.integers(0, len(raw) - 1), label="byte")] ^= data.draw(
            st.integers(1, 255), label="xor"
        )
        text = raw.decode("utf-8", errors="replace")
    elif how == "layout":  # the same content, other key order and spacing
        text = json.dumps(dict(reversed(list(original.items()))), separators=(",", ":"))
    elif how != "none":
        content = json.loads(text)
        _edit(content, how, lambda strategy: data.draw(strategy))
        text = json.dumps(content)
    target.write_text(text)
    try:
        content = json.loads(text)
        same = isinstance(content, dict) and _checked(content) == _checked(original)
    except ValueError:
        same = False
    note(f"{how}: {'the same content' if same else 'changed'}")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        found = finished_cells(out, plan)
    warned = [str(w.message) for w in caught if issubclass(w.category, SweepWarning)]
    record(f"sweep cell: {how}", accepted=target.stem in found)
    others = {c.stem for c in cells} - {target.stem}
    assert others <= set(found)  # the untouched cells are reused
    if same:
        assert target.stem in found and not warned
        assert found[target.stem]["episodes"] == original["episodes"]
    else:
        assert target.stem not in found
        (message,) = warned
        assert f"is not this sweep's finished cell {target.stem}: " in message
        assert message.endswith("; it runs again")
