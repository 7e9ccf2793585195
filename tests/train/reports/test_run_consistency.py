"""NEES and NIS per episode (train/reports/consistency.py): chi-square means on samples drawn from
the claimed covariance, a singular covariance counted by its rank."""

from __future__ import annotations

import numpy as np
import pytest

from observer_gym.train.reports.consistency import (
    chi_square_band,
    episode_consistency,
    nees_flag,
    nees_per_step,
)


def test_errors_drawn_from_the_covariance_give_a_mean_nees_of_its_dimension():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(4, 4))
    P = A @ A.T + 0.1 * np.eye(4)
    P = np.diag([1e-6, 1e-2, 1.0, 10.0]) @ P @ np.diag([1e-6, 1e-2, 1.0, 10.0])  # mixed units
    steps = 4000
    truth = rng.normal(size=(steps, 4))
    errors = rng.multivariate_normal(np.zeros(4), P, size=steps)
    nees, dof = nees_per_step(truth + errors, [P] * steps, truth)
    assert np.all(dof == 4)
    # mean of chi2(4) over 4000 samples: 4 +- 3 * sqrt(8 / 4000) = 4 +- 0.13
    assert nees.mean() == pytest.approx(4.0, abs=0.15)


def test_a_direction_known_exactly_is_left_out_of_the_dof():
    # rate = -theta / tau exactly: the (theta, rate) block has rank 1.
    tau = 0.05
    P = np.array([[1e-4, -1e-4 / tau], [-1e-4 / tau, 1e-4 / tau**2]])
    rng = np.random.default_rng(1)
    theta_err = rng.normal(scale=1e-2, size=2000)
    errors = np.column_stack([theta_err, -theta_err / tau + 1e-3 * rng.normal(size=2000)])
    nees, dof = nees_per_step(errors, [P] * 2000, np.zeros((2000, 2)))
    assert np.all(dof == 1)
    assert nees.mean() == pytest.approx(1.0, abs=0.1)


def test_entries_with_zero_variance_are_not_counted_and_nan_gives_no_nees():
    P = np.diag([1.0, 0.0, 4.0])
    nees, dof = nees_per_step(np.array([[1.0, 5.0, 2.0]]), [P], np.zeros((1, 3)))
    assert dof[0] == 2 and nees[0] == pytest.approx(1.0 + 1.0)
    nees, dof = nees_per_step(np.array([[np.nan, 0.0, 0.0]]), [P], np.zeros((1, 3)))
    assert np.isnan(nees[0]) and dof[0] == 0


def test_episode_means_skip_steps_without_a_value():
    record = {
        "nees": np.array([np.nan, 2.0, 4.0]),
        "nees_dof": np.array([0, 2, 2]),
        "nis": np.array([np.nan, np.nan, np.nan]),
        "nis_dof": np.array([0, 0, 0]),
    }
    out = episode_consistency(record)
    assert out["nees_mean"] == 3.0 and out["nees_ratio"] == 1.5
    assert out["nis_mean"] is None
    assert episode_consistency({"nees": None}) == {}


def test_the_band_is_chi_square_with_two_dof_in_closed_form():
    # chi-square(2) is exponential with mean 2: F^-1(p) = -2 ln(1 - p), so the band of
    # chi-square(2) / 2 is (-ln 0.975, -ln 0.025).
    low, high = chi_square_band(2.0)
    assert low == pytest.approx(-np.log(0.975), rel=1e-9)
    assert high == pytest.approx(-np.log(0.025), rel=1e-9)


def test_a_cell_is_flagged_by_its_summed_nees_against_its_summed_dof():
    episodes = [{"nees_mean": 3.9, "nees_dof": 4.0}, {"nees_mean": 4.3, "nees_dof": 4.0}]
    cell = nees_flag(episodes)
    assert cell.nees_ratio == pytest.approx(8.2 / 8.0)
    assert cell.band == chi_square_band(8.0) and cell.consistent
    cautious = nees_flag([{"nees_mean": 0.04, "nees_dof": 4.0}] * 10)  # NEES/dof 0.01
    assert cautious.consistent is False and cautious.band[0] > 0.01
    confident = nees_flag([{"nees_mean": 360.0, "nees_dof": 4.0}] * 10)  # NEES/dof 90
    assert confident.consistent is False and confident.band[1] < 90.0
    assert nees_flag([{}, {"nees_mean": None, "nees_dof": None}]) == (None, None, None)


def test_ball_catcher_nees_counts_the_free_flight_only():
    # At 2 px of pixel noise seed 0's ball hits the box off the hole: after its first touch
    # it bounces, which no ballistic model predicts, and those steps carry no NEES or NIS.
    import gymnasium as gym

    from observer_gym.train.experiments.episode import EpisodeSpec, run_episode

    options = {"measurement_noise_px": 2.0}
    spec = EpisodeSpec.of(
        "observer_gym/BallCatcher-v1",
        "kf-measurements",
        "intercept",
        0,
        max_steps=150,
        env_kwargs=options,
    )
    record = run_episode(spec)
    env = gym.make("observer_gym/BallCatcher-v1", obs_mode="state", **options)
    env.reset(seed=0)
    in_flight = [True]
    for action in record["actions"]:
        *_, info = env.step(action)
        in_flight.append(info["ball_in_flight"])
    env.close()
    in_flight = np.array(in_flight)
    assert in_flight.any() and not in_flight.all()  # it touched the box
    assert np.all(np.isnan(record["nees"][~in_flight])) and np.all(
        record["nees_dof"][~in_flight] == 0
    )
    assert np.all(np.isnan(record["nis"][~in_flight]))
    assert np.isfinite(record["nees"][in_flight][1:]).all()


def test_the_study_pools_each_cell_and_brackets_its_ratio():
    from observer_gym.train.experiments.consistency_study import option_table, summarise

    rng = np.random.default_rng(3)
    rows = [
        {
            "observer": "kf-measurements",
            "latency_s": v,
            "nees_mean": n,
            "nees_dof": 4.0,
            "nis_ratio": 1.0,
        }
        for v, scale in ((0.0, 1.0), (0.1, 50.0))
        for n in scale * rng.chisquare(4, size=12)
    ]
    summary = summarise(rows, "latency_s")
    for value, scale in ((0.0, 1.0), (0.1, 50.0)):
        cell = summary["kf-measurements", value]
        pooled = [r["nees_mean"] for r in rows if r["latency_s"] == value]
        ratio = sum(pooled) / (4.0 * len(pooled))
        assert cell["consistency"]["nees_ratio"] == pytest.approx(ratio)
        low, high = cell["interval"]
        assert low < ratio < high
        assert cell["consistency"]["consistent"] == (scale == 1.0)
    table = option_table("latency_s", summary)
    assert "⚠" in table.splitlines()[-1].split("|")[3] and "NIS 1.00" in table
