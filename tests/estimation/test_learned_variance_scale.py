"""The post-hoc variance scale and the fusion gate of the learned observers
(estimation/learned/variance_scale.py), and BallTable's shipped scale in use."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest

from observer_gym.estimation import VisionObserver
from observer_gym.estimation.ball_table.learned import WEIGHTS
from observer_gym.estimation.learned.variance_scale import (
    FuseEvery,
    load_variance_scale,
    variance_scale,
)


def test_the_gate_passes_the_first_frame_and_then_one_in_every_n():
    gate = FuseEvery(3)
    assert [gate.new_frame() for _ in range(7)] == [True, False, False, True, False, False, True]
    gate.reset()
    assert gate.new_frame() is True
    one = FuseEvery(1)
    assert all(one.new_frame() for _ in range(4))


@pytest.mark.parametrize("every", [0, -2, 1.5, True])
def test_a_bad_spacing_is_refused(every):
    with pytest.raises(ValueError, match="fuse_every must be an integer >= 1"):
        FuseEvery(every)


def test_a_report_without_a_scale_scales_by_one_and_a_bad_one_is_refused():
    assert np.array_equal(variance_scale({}, "rgb", 3), np.ones(3))
    report = {"variance_scale": {"measurements": [2.0, 3.0, 4.0]}}
    assert variance_scale(report, "measurements", 3).tolist() == [2.0, 3.0, 4.0]
    with pytest.raises(ValueError, match="3 positive finite numbers"):
        variance_scale({"variance_scale": {"rgb": [1.0, -1.0, 1.0]}}, "rgb", 3)
    with pytest.raises(ValueError, match="obs_mode must be one of"):
        variance_scale(report, "state", 3)


def test_learned_reports_the_networks_variance_times_the_shipped_scale():
    report = json.loads(WEIGHTS.with_suffix(".json").read_text())
    scale = load_variance_scale(report, "measurements", 8)
    env = VisionObserver(
        gym.make("observer_gym/BallTable-v0", obs_mode="measurements"), observer="learned"
    )
    try:
        env.reset(seed=0)
        _, _, _, _, info = env.step(np.zeros(2, dtype=np.float32))
        observer = env.pipeline  # the LearnedObserver
        now_s = float(info["time_s"])
        features = observer.features.vector(now_s, np.zeros(2))
        _, raw = observer.net.predict(features)
        at_age = scale.at(observer.features.newest_age_s(now_s))
        assert np.allclose(np.diag(info["estimate"]["covariance"]), np.diag(raw) * at_age)
    finally:
        env.close()
