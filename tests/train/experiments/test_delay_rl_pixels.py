"""BallTable's pixel input of the random-delay study (train/experiments/delay_rl/): trained
at the moderate level only, evaluated at every level; the plan, the folder's resume with
an added input, and the table's cells for the levels it does not train at."""

from __future__ import annotations

import pytest

from observer_gym.envs.json_file import read_json
from observer_gym.train.experiments.delay_rl import StudyPlan, StudyTable, inputs_for
from observer_gym.train.experiments.delay_rl.layout import PLAN_FILE
from observer_gym.train.experiments.delay_rl.plan import PIXEL_FRAMES
from observer_gym.train.experiments.delay_rl.run import _add_inputs, check_study_folder
from observer_gym.train.experiments.delay_rl.table import table_markdown
from observer_gym.train.reports.outputs import write_json_atomic
from observer_gym.train.rl.hyperparams import resolve_hyperparams

BT = "BallTable-v0"
LEVELS = ("none", "moderate", "heavy")
PUBLISHED = ("newest", "stack", "kf-latency", "kf", "truth")  # the inputs of the first study


def _plan(**fields):
    values = {
        "env_id": BT,
        "levels": LEVELS,
        "inputs": (*PUBLISHED, "pixels"),
        "seeds": (0, 1, 2, 3, 4),
        "timesteps": 1000,
        "eval_episodes": 3,
    }
    return StudyPlan(**{**values, **fields})


def test_the_pixel_input_is_the_tuned_rgb_recipe_on_ball_table_only():
    pixels = inputs_for(BT)["pixels"]
    assert (pixels.obs, pixels.observer, dict(pixels.hyperparams)) == ("rgb", None, {})
    assert pixels.trained_only_at == "moderate" and not pixels.delay_free
    assert pixels.reference_observer is None  # no classical controller reads frames here
    image = resolve_hyperparams(BT, "ppo", "rgb")["image"]
    assert image["frame_stack"] == PIXEL_FRAMES and image["encoder"] == "ball_table"
    assert "pixels" not in inputs_for("BallCatcher-v1")
    with pytest.raises(ValueError, match="unknown input 'pixels'; allowed: newest, stack"):
        _plan(env_id="BallCatcher-v1")


def test_pixels_train_at_moderate_only_and_are_evaluated_at_every_level():
    plan = _plan()
    cells = plan.train_cells()
    assert [c for c in cells if c[1] == "pixels"] == [("moderate", "pixels")]
    # the published 13 trainings are unchanged: 4 inputs at 3 levels, the truth once
    assert [c for c in cells if c[1] != "pixels"] == _plan(inputs=PUBLISHED).train_cells()
    evals = plan.eval_cells()
    assert [c for c in evals if c[1] == "pixels"] == [("moderate", "pixels", at) for at in LEVELS]
    assert len(evals) == 23 + 3
    assert [plan.trained_at(level, "pixels") for level in LEVELS] == [None, "moderate", None]


def test_a_plan_of_pixels_without_the_moderate_level_is_refused():
    with pytest.raises(ValueError, match="'pixels' trains at the moderate level only: add"):
        _plan(levels=("none", "heavy"))


def test_the_published_inputs_record_as_before():
    """The inputs of the first study record the same settings as before ``pixels``
    existed, so its folders still load and re-derive."""
    settings = _plan().as_dict()["input_settings"]
    fields = {"name", "obs", "observer", "hyperparams", "reference_observer", "delay_free"}
    for name in PUBLISHED:
        assert set(settings[name]) == {*fields, "summary"}
    assert settings["pixels"]["trained_only_at"] == "moderate"
    assert StudyPlan.from_dict(_plan().as_dict()) == _plan()


def test_a_plan_extends_a_held_one_by_inputs_only():
    held = _plan(inputs=PUBLISHED)
    assert _plan().extends(held)
    assert not held.extends(held) and not held.extends(_plan())
    assert not _plan(timesteps=2000).extends(held)
    assert not _plan(seeds=(0, 1)).extends(held)


def test_a_folder_gets_the_added_input_and_keeps_its_first_versions(tmp_path):
    held = _plan(inputs=PUBLISHED)
    write_json_atomic(tmp_path / PLAN_FILE, {**held.as_dict(), "versions": {"first": "1"}})
    check_study_folder(tmp_path, _plan())  # adds an input: accepted
    with pytest.raises(ValueError, match="holds another study"):
        check_study_folder(tmp_path, _plan(timesteps=2000))
    said = []
    _add_inputs(tmp_path, _plan(), said.append)
    data = read_json(tmp_path / PLAN_FILE)
    assert StudyPlan.from_dict(data) == _plan()
    assert data["versions"] == {"first": "1"}
    assert [a["inputs"] for a in data["inputs_added"]] == [["pixels"]]
    assert said == ["added input(s) pixels to the study"]


def _stats(iqm_mm):
    value = iqm_mm / 1000.0
    return {"iqm": value, "iqm_low": value - 0.001, "iqm_high": value + 0.001}


def test_the_table_says_where_pixels_were_not_trained_and_gives_their_shift():
    plan = _plan(inputs=("newest", "pixels"))
    scores = {  # (trained at, input, at) -> IQM in mm
        ("none", "newest", "none"): 60.0,
        ("moderate", "newest", "none"): 57.0,
        ("moderate", "newest", "moderate"): 68.0,
        ("moderate", "newest", "heavy"): 78.0,
        ("heavy", "newest", "heavy"): 79.0,
        ("moderate", "pixels", "none"): 20.0,
        ("moderate", "pixels", "moderate"): 25.0,
        ("moderate", "pixels", "heavy"): 40.0,
    }
    assert set(scores) == set(plan.eval_cells())
    delivery = {
        level: {
            "latency_s": 0.0,
            "latency_jitter_s": 0.0,
            "frame_drop_prob": 0.0,
            "out_of_order_fraction": 0.0,
            "newest_age_mean_s": 0.0,
            "frames_delivered": 1,
        }
        for level in LEVELS
    }
    table = StudyTable(
        plan=plan.as_dict(),
        metric={
            "key": "d",
            "label": "distance",
            "unit": "mm",
            "scale": 1000.0,
            "digits": 2,
            "better": "lower",
        },
        cells=[
            {"trained_at": t, "input": n, "at": a, "metric": _stats(v)}
            for (t, n, a), v in scores.items()
        ],
        references=[],
        delivery=delivery,
        budget={
            "seed_runs": 20,
            "timesteps_per_seed": 1000,
            "env_steps": 20000,
            "training_cpu_hours": 0.1,
            "wall_time_hours": 0.1,
            "invocations": 1,
            "cpus": [2],
        },
    )
    lines = table_markdown(table).splitlines()
    first = next(line for line in lines if line.startswith("| pixels: the last 4 camera"))
    cells = [c.strip() for c in first.strip("|").split("|")][1:]
    assert cells == [
        "not trained (moderate only)",
        "25.00 [24.00, 26.00]",
        "not trained (moderate only)",
    ]
    shift = next(line for line in lines if line.startswith("| pixels "))
    cells = [c.strip() for c in shift.strip("|").split("|")][1:]
    assert cells == [
        "20.00 (-5.00, not trained there)",
        "25.00",
        "40.00 (+15.00, not trained there)",
    ]
    newest = next(line for line in lines if line.startswith("| newest "))
    # the inputs trained at every level keep both changes
    assert "57.00 (-11.00, -3.00)" in newest


def test_pixels_on_ball_catcher_is_one_line_and_writes_nothing(tmp_path, capsys):
    from observer_gym.train.cli import main

    out = tmp_path / "study"
    argv = ["study", "delay-rl", "--env", "BallCatcher-v1", "--inputs", "pixels"]
    assert main([*argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and "unknown input 'pixels'; allowed: newest" in err[0], err
    assert not out.exists()
