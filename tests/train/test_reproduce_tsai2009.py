"""``observer-gym reproduce tsai2009``: Table 2 of the self-tuning Kalman filter's paper.

The fast tests run a few short closed loops; the slow ones run the paper's 20 runs per
noise level (sigma_n = 0 and 10, 40 s each) and check the issue's targets against it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from observer_gym.train.cli import main
from observer_gym.train.reproduce import tsai2009


def test_short_study_orders_the_filters_as_the_paper(capsys):
    study = tsai2009.run_study([0, 10], runs=2, steps=150)
    mse = study["mse"]
    kf10, st10 = mse["kf"][1].mean(axis=0), mse["stkf"][1].mean(axis=0)
    # y_i, d_x and all three rates: the STKF at least halves the KF's MSE at sigma_n = 10.
    assert np.all(st10[[1, 2, 4, 5]] < 0.6 * kf10[[1, 2, 4, 5]])
    # With R = R_0 = 5 px^2 against a true 33 px^2 the KF follows the measurements: its
    # position MSE is a large part of the measurement variance sigma^2 / 3 + 1/12.
    variance = 100 / 3 + 1 / 12
    assert np.all((0.3 * variance < kf10[:3]) & (kf10[:3] < 0.8 * variance))
    for f in tsai2009.FILTERS:
        assert np.all(mse[f][0].mean(axis=0)[:3] <= tsai2009.POSITION_MSE_BOUND_PX2)
    assert study["ended_early"] == 0


def test_the_targets_turning_is_what_sets_x_i_apart():
    """Why x_i misses its Table 2 target (docs/target_follower.md): without (44)'s turning,
    x_i's STKF/KF ratio is y_i's and within 1.25x the paper's; with it, x_i's ratio and
    its rate's grow, and y_i's and d_x's do not move."""
    ratios = {}
    for turn in (0.0, tsai2009.PROFILE_TURN_RATE_RADPS):
        mse = tsai2009.run_study([10], runs=3, steps=400, turn_rate_radps=turn)["mse"]
        ratios[turn] = mse["stkf"][0].mean(axis=0) / mse["kf"][0].mean(axis=0)
    straight, turning = ratios[0.0], ratios[tsai2009.PROFILE_TURN_RATE_RADPS]
    paper = np.array(tsai2009.PAPER_TABLE2[10][1]) / np.array(tsai2009.PAPER_TABLE2[10][0])
    assert abs(straight[0] - straight[1]) < 0.1  # x_i as y_i
    assert straight[0] <= tsai2009.RATIO_SLACK * paper[0]
    assert turning[0] > straight[0] + 0.2 and turning[3] > straight[3] + 0.3
    np.testing.assert_allclose(turning[[1, 2, 4, 5]], straight[[1, 2, 4, 5]], atol=0.1)


def test_cli_prints_table_2_and_writes_the_plot_and_json(tmp_path, capsys):
    code = main(
        [
            "reproduce",
            "tsai2009",
            "--runs",
            "1",
            "--steps",
            "40",
            "--sigmas",
            "0",
            "5",
            "10",
            "--out",
            str(tmp_path),
        ]
    )
    assert code == 0
    out = capsys.readouterr().out
    assert "Table 2" in out and "16.7670 -> 8.8669" in out  # the paper's x_i at sigma_n = 10
    assert (tmp_path / "fig8_mse_vs_noise.png").stat().st_size > 10_000
    results = json.loads((tmp_path / "results.json").read_text())
    assert results["sigmas"] == [0, 5, 10]
    assert len(results["mse_mean"]["stkf"]) == 3 and len(results["mse_mean"]["stkf"][0]) == 6


@pytest.fixture(scope="module")
def paper_study():
    study = tsai2009.run_study([0, 10], runs=20, steps=400)
    return tsai2009.check_targets([0, 10], study["mse"])


@pytest.mark.slow
def test_table_2_targets_met(paper_study):
    # sigma_n = 10: the STKF below the KF for all six quantities, and its MSE ratio no
    # worse than 1.25x the paper's for y_i, d_x, y_i^t', d_x^t' (x_i and x_i^t': below).
    assert all(paper_study["sigma10_stkf_below_kf"])
    assert all(paper_study["sigma10_ratio_within_slack"][q] for q in (1, 2, 4, 5))
    # sigma_n = 0: both filters' position MSE <= 0.1 px^2.
    assert all(all(v) for v in paper_study["sigma0_position_mse_ok"].values())


@pytest.mark.slow
@pytest.mark.xfail(
    strict=True,
    reason="x_i and its rate: the STKF's large R (41) lags the lateral image acceleration of "
    "the turning target (44); ratios 0.95 and 0.71 against the paper's 0.53 and 0.48",
)
def test_table_2_x_ratios_within_slack(paper_study):
    assert paper_study["sigma10_ratio_within_slack"][0]
    assert paper_study["sigma10_ratio_within_slack"][3]
