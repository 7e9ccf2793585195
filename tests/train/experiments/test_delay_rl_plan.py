"""The random-delay study's plan (train/experiments/delay_rl/plan.py) and how each level's
frames arrive (delivery.py), against the sensor model's closed forms."""

from __future__ import annotations

import math

import pytest

from observer_gym.train.experiments.delay_rl import LEVELS, StudyPlan, inputs_for
from observer_gym.train.experiments.delay_rl.delivery import measure_delivery

BT = "BallTable-v0"
ALL_LEVELS = ("none", "moderate", "heavy")
ALL_INPUTS = ("newest", "stack", "kf-latency", "kf", "truth")


def _plan(**fields):
    values = {
        "env_id": BT,
        "levels": ALL_LEVELS,
        "inputs": ALL_INPUTS,
        "seeds": (0, 1, 2, 3, 4),
        "timesteps": 1000,
        "eval_episodes": 3,
    }
    return StudyPlan(**{**values, **fields})


def test_the_truth_trains_once_and_the_moderate_agents_are_evaluated_everywhere():
    plan = _plan()
    cells = plan.train_cells()
    # 4 inputs the delay reaches at 3 levels, the truth once
    assert len(cells) == 13 and cells.count(("none", "truth")) == 1
    assert not [c for c in cells if c[1] == "truth" and c[0] != "none"]
    evals = plan.eval_cells()
    # each agent at its level (12 + 1), the moderate ones at 2 more (8), the truth at 2 more
    assert len(evals) == 23
    for name in ("newest", "stack", "kf-latency", "kf"):
        assert {at for lv, n, at in evals if n == name and lv == "moderate"} == set(ALL_LEVELS)
        assert {at for lv, n, at in evals if n == name and lv == "heavy"} == {"heavy"}
    assert {at for _, n, at in evals if n == "truth"} == set(ALL_LEVELS)
    assert plan.trained_at("heavy", "truth") == "none"


def test_the_plan_round_trips_through_its_record_and_refuses_another_versions():
    plan = _plan(levels=("moderate", "heavy"), inputs=("stack", "truth"))
    data = plan.as_dict()
    assert StudyPlan.from_dict(data) == plan
    assert data["level_values"]["heavy"] == LEVELS["heavy"]._asdict()
    changed = {**data, "level_values": {**data["level_values"], "heavy": {"latency_s": 0.2}}}
    with pytest.raises(ValueError, match="other delay levels or input settings"):
        StudyPlan.from_dict(changed)


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"levels": ("none", "severe")}, "unknown level 'severe'; allowed: none, moderate, heavy"),
        ({"inputs": ()}, "at least one input"),
        ({"inputs": ("kf", "kf")}, "each input once"),
        ({"timesteps": 0}, "timesteps must be an integer >= 1"),
        ({"seeds": (1, 1)}, "distinct"),
        ({"env_id": "BallJuggler-v0"}, "unknown env"),
    ],
)
def test_a_bad_plan_is_refused(fields, message):
    with pytest.raises(ValueError, match=message):
        _plan(**fields)


def test_each_system_feeds_its_own_filters():
    catcher = inputs_for("BallCatcher-v1")
    assert catcher["kf"].observer == "kf-at-delivery-measurements"
    assert catcher["kf-latency"].observer == "kf-latency-measurements"
    table = inputs_for(BT)
    assert table["kf"].observer == "kf-measurements"
    assert table["kf-latency"].hyperparams == {"features": "belief"}
    assert table["stack"].hyperparams == {"measurement_stack": 4}


def test_without_delay_every_frame_arrives_at_once_in_order():
    d = measure_delivery(BT, LEVELS["none"].env_kwargs(), min_frames=400, seed=0)
    # one frame per step (50 frames/s, one step per frame), none late or lost
    assert d.frames_delivered == d.steps
    assert d.frames_out_of_order == 0 and d.newest_age_mean_s == 0.0


def test_a_fixed_latency_ages_the_newest_frame_by_exactly_the_latency():
    d = measure_delivery(BT, {"latency_s": 0.04}, min_frames=400, seed=0)
    assert d.frames_out_of_order == 0
    # after the first two steps every step's newest frame was captured 40 ms before it
    assert d.newest_age_max_s == pytest.approx(0.04)
    assert d.newest_age_mean_s == pytest.approx(0.04, abs=1e-3)


def test_drops_and_jitter_lose_and_reorder_frames_as_the_sensor_model_says():
    p = 0.2
    d = measure_delivery(BT, {"frame_drop_prob": p}, min_frames=800, seed=0)
    kept = d.frames_delivered / d.steps
    # binomial: within 4 standard deviations of 1 - p
    assert abs(kept - (1 - p)) < 4 * math.sqrt(p * (1 - p) / d.steps)
    heavy = measure_delivery(BT, LEVELS["heavy"].env_kwargs(), min_frames=400, seed=0)
    # 30 ms jitter on frames 20 ms apart: a frame overtakes an older one often
    assert 0.1 < heavy.out_of_order_fraction < 0.5
