"""``observer-gym reproduce tsai2009``: Table 2 of the self-tuning Kalman filter's paper.

The fast tests run a few short closed loops; the slow ones run the paper's 20 runs per
noise level (sigma_n = 0 and 10, 40 s each) and check the issue's targets against it."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from observer_gym.train.cli import main
from observer_gym.train.experiments.reproduce import tsai2009


def _tables(text: str) -> dict[str, list[list[str]]]:
    """The Markdown tables of ``text`` (cells stripped, rule and header rows dropped), each
    under the first words (up to ":") of the line above it."""
    tables, title, rows = {}, None, None
    for line in text.splitlines():
        if line.startswith("|"):
            if rows is None:  # the header row
                rows = tables[title] = []
            elif not line.startswith("|-"):
                rows.append([c.strip() for c in line.strip("|").split("|")])
        else:
            title, rows = line.split(":")[0], None
    return tables


def _ours_and_paper(cell: str) -> tuple[str, str]:
    match = re.fullmatch(r"(\S+) \((\S+)\)", cell)
    assert match, cell
    return match[1], match[2]


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


@pytest.mark.slow  # two reproductions: 3 s (load ~2)
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
    table = {(row[0], row[1]): row[2:] for row in _tables(out)["Table 2"]}
    # the paper's x_i at sigma_n = 10, KF and STKF
    assert _ours_and_paper(table["10", "KF"][0])[1] == "16.7670"
    assert _ours_and_paper(table["10", "STKF"][0])[1] == "8.8669"
    assert (tmp_path / "fig8_mse_vs_noise.png").stat().st_size > 10_000
    results = json.loads((tmp_path / "results.json").read_text())
    assert results["sigmas"] == [0, 5, 10]
    assert len(results["mse_mean"]["stkf"]) == 3 and len(results["mse_mean"]["stkf"][0]) == 6


def test_cli_table_2_shows_the_numbers_of_results_json(tmp_path, capsys):
    """The smallest run the CLI allows: every number of the printed Table 2 and Fig. 8 data
    is results.json's (ours, the paper's, the ratios, the targets), and the output names
    the files it wrote."""
    code = main(
        [
            *("reproduce", "tsai2009", "--runs", "1", "--steps", "10"),
            *("--sigmas", "0", "10", "--out", str(tmp_path)),
        ]
    )
    assert code == 0
    out = capsys.readouterr().out
    results = json.loads((tmp_path / "results.json").read_text())
    sigmas, mean, paper = results["sigmas"], results["mse_mean"], results["paper_table2"]
    targets = results["targets"]
    tables = _tables(out)
    table = {(row[0], row[1]): row[2:] for row in tables["Table 2"]}
    assert [key[0] for key in table] == ["10"] * 4 + ["0"] * 4  # the paper's order
    ok0 = targets["sigma0_position_mse_ok"]
    expected_met = {
        10: [
            "yes" if below and within else "no"
            for below, within in zip(
                targets["sigma10_stkf_below_kf"], targets["sigma10_ratio_within_slack"], strict=True
            )
        ],
        0: ["yes" if a and b else "no" for a, b in zip(ok0["kf"], ok0["stkf"], strict=True)]
        + ["-"] * 3,
    }
    for s in (10, 0):
        i = sigmas.index(s)
        kf, st = mean["kf"][i], mean["stkf"][i]
        paper_kf, paper_st = paper[str(s)]
        for name, ours, theirs in (("KF", kf, paper_kf), ("STKF", st, paper_st)):
            cells = [_ours_and_paper(c) for c in table[str(s), name]]
            assert cells == [(f"{a:.4f}", f"{b:.4f}") for a, b in zip(ours, theirs, strict=True)]
        ratios = [_ours_and_paper(c) for c in table[str(s), "STKF / KF"]]
        assert ratios == [
            (f"{a / b:.2f}", f"{c / d:.2f}")
            for a, b, c, d in zip(st, kf, paper_st, paper_kf, strict=True)
        ]
        assert [c.split(":")[0] for c in table[str(s), "target met"]] == expected_met[s]
    n_met = (expected_met[10] + expected_met[0]).count("yes")
    assert f"Targets met: {n_met} of 9." in out
    sweep = tables["Fig. 8 data"]
    assert [row[0] for row in sweep] == ["0", "10"]
    for i, row in enumerate(sweep):
        assert row[1:] == [
            f"{a:.3f} / {b:.3f}" for a, b in zip(mean["kf"][i], mean["stkf"][i], strict=True)
        ]
    assert f"Wrote {tmp_path / 'fig8_mse_vs_noise.png'} and {tmp_path / 'results.json'}" in out
    # no reprs of dicts, lists of bools, unrounded floats or arrays
    assert not re.search(r"\{'|\[(True|False)|\d\.\d{6,}|array\(", out)


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
