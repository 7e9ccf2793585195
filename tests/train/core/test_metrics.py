"""Closed-loop metrics on synthetic arrays, against values worked out by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from observer_gym.train.core.metrics import (
    distance_from_centre_m,
    episode_metrics,
    rms_norm,
    rmse,
    settling_time_s,
    summarize,
    time_within_s,
)

DT_S = 0.02


def times_s(n: int) -> np.ndarray:
    return DT_S * np.arange(n)


def test_settling_time_after_entering_and_leaving_the_band():
    # In the band at t = 0.02, out at 0.04 (exactly 1 cm is out), in from 0.06 to the end.
    distance_m = np.array([0.05, 0.005, 0.01, 0.008, 0.004])
    assert settling_time_s(times_s(5), distance_m) == pytest.approx(0.06)
    # Intervals ending at 0.02, 0.06 and 0.08 are inside: 3 steps of 0.02 s.
    assert time_within_s(times_s(5), distance_m) == pytest.approx(0.06)


def test_never_settling_episode():
    distance_m = np.array([0.02, 0.005, 0.006, 0.03])  # in for two steps, out at the end
    assert settling_time_s(times_s(4), distance_m) is None
    assert time_within_s(times_s(4), distance_m) == pytest.approx(0.04)
    assert settling_time_s(times_s(3), [0.02, 0.03, 0.04]) is None
    assert time_within_s(times_s(3), [0.02, 0.03, 0.04]) == 0.0


def test_episode_inside_from_the_start():
    distance_m = np.full(6, 0.001)
    assert settling_time_s(times_s(6), distance_m) == 0.0
    # The reset sample ends no interval: 5 steps of 0.02 s.
    assert time_within_s(times_s(6), distance_m) == pytest.approx(0.10)


def test_band_radius_is_a_parameter():
    distance_m = np.array([0.05, 0.03, 0.01])
    assert settling_time_s(times_s(3), distance_m, tolerance_m=0.04) == pytest.approx(0.02)
    assert time_within_s(times_s(3), distance_m, tolerance_m=0.04) == pytest.approx(0.04)


def test_time_series_must_match():
    with pytest.raises(ValueError, match="same"):
        settling_time_s(times_s(3), [0.1, 0.2])
    with pytest.raises(ValueError, match="same"):
        time_within_s([], [])


def test_distance_rms_and_rmse():
    np.testing.assert_allclose(distance_from_centre_m([[0.03, 0.04], [0.0, -0.01]]), [0.05, 0.01])
    # |v| = 5 and 0: sqrt((25 + 0) / 2)
    assert rms_norm(np.array([[3.0, 4.0], [0.0, 0.0]])) == pytest.approx(math.sqrt(12.5))
    assert rms_norm(np.zeros((0, 2))) == 0.0
    truth = np.array([[1.0, 1.0], [2.0, 2.0], [0.0, 0.0]])
    estimate = truth + np.array([[0.3, -0.4], [0.0, 0.0], [0.0, 1.0]])
    # errors 0.5, 0, 1: sqrt((0.25 + 0 + 1) / 3)
    assert rmse(estimate, truth) == pytest.approx(math.sqrt(1.25 / 3))
    with pytest.raises(ValueError, match="shape"):
        rmse(estimate, truth[:2])


def _state(ball_pos_m: np.ndarray, ball_vel_mps: np.ndarray | None = None) -> np.ndarray:
    state = np.zeros((len(ball_pos_m), 8))
    state[:, 0:2] = ball_pos_m
    if ball_vel_mps is not None:
        state[:, 2:4] = ball_vel_mps
    return state


def test_episode_metrics_on_a_synthetic_episode():
    # The ball moves in along x: 5, 3, 0.6, 0.3, 0.2 cm from the centre; 4 steps.
    pos_m = np.array([[0.05, 0.0], [0.03, 0.0], [0.006, 0.0], [0.003, 0.0], [0.002, 0.0]])
    vel_mps = np.array([[-1.0, 0.0]] * 5)
    state = _state(pos_m, vel_mps)
    actions_rad = np.array([[0.03, 0.04], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0]])
    rewards = np.array([0.5, 0.6, 0.9, 1.0])
    estimate = state.copy()
    estimate[:, 1] += 0.001  # 1 mm off in y throughout
    estimate[2, 2] += 0.2  # 0.2 m/s off in vx at one of five samples

    metrics = episode_metrics(
        times_s(5), state, actions_rad, rewards, estimate=estimate, solver_failures=3
    )
    assert metrics["steps"] == 4
    assert metrics["duration_s"] == pytest.approx(0.08)
    assert metrics["start_distance_m"] == pytest.approx(0.05)
    assert metrics["mean_distance_m"] == pytest.approx((0.05 + 0.03 + 0.006 + 0.003 + 0.002) / 5)
    assert metrics["final_distance_m"] == pytest.approx(0.002)
    assert metrics["settling_time_s"] == pytest.approx(0.04)
    assert metrics["time_within_s"] == pytest.approx(0.06)
    assert metrics["effort_rms_rad"] == pytest.approx(math.sqrt(0.05**2 / 4))
    assert metrics["position_rmse_m"] == pytest.approx(0.001)
    assert metrics["velocity_rmse_mps"] == pytest.approx(math.sqrt(0.2**2 / 5))
    assert metrics["return"] == pytest.approx(3.0)
    assert metrics["solver_failures"] == 3
    assert metrics["terminated"] is False

    oracle = episode_metrics(times_s(5), state, actions_rad, rewards)
    assert oracle["position_rmse_m"] == 0.0 and oracle["velocity_rmse_mps"] == 0.0

    with pytest.raises(ValueError, match="inconsistent"):
        episode_metrics(times_s(5), state, actions_rad[:3], rewards)


def _episode(settling_s: float | None, **values) -> dict:
    base = {
        "settling_time_s": settling_s,
        "mean_distance_m": 0.0,
        "final_distance_m": 0.0,
        "time_within_s": 0.0,
        "effort_rms_rad": 0.0,
        "position_rmse_m": 0.0,
        "velocity_rmse_mps": 0.0,
        "return": 0.0,
        "solver_failures": 0,
        "terminated": False,
    }
    return {**base, **values}


def test_summary_statistics():
    episodes = [
        _episode(0.5, mean_distance_m=0.01, final_distance_m=0.002, solver_failures=2),
        _episode(None, mean_distance_m=0.05, final_distance_m=0.2, terminated=True),
        _episode(1.5, mean_distance_m=0.03, final_distance_m=0.004, solver_failures=1),
        _episode(0.7, time_within_s=8.0, effort_rms_rad=0.04, position_rmse_m=0.004),
    ]
    summary = summarize(episodes)
    assert summary["episodes"] == 4
    assert summary["fraction_settled"] == 0.75
    assert summary["settling_time_mean_s"] == pytest.approx(0.9)
    assert summary["settling_time_median_s"] == pytest.approx(0.7)
    assert summary["settling_time_max_s"] == pytest.approx(1.5)
    assert summary["mean_distance_m"] == pytest.approx(0.0225)
    assert summary["final_distance_m"] == pytest.approx(0.0515)
    assert summary["time_within_s"] == pytest.approx(2.0)
    assert summary["effort_rms_rad"] == pytest.approx(0.01)
    assert summary["position_rmse_m"] == pytest.approx(0.001)
    assert summary["solver_failures"] == 3
    assert summary["terminated"] == 1


def test_summary_when_nothing_settles():
    summary = summarize([_episode(None), _episode(None)])
    assert summary["fraction_settled"] == 0.0
    assert summary["settling_time_mean_s"] is None
    assert summary["settling_time_median_s"] is None
    assert summary["settling_time_max_s"] is None
    with pytest.raises(ValueError, match="no episodes"):
        summarize([])
