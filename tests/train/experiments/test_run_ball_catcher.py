"""``observer-gym run`` on BallCatcher-v1: catch rate with its interval, plots, options."""

from __future__ import annotations

import json

import pytest
from scipy.stats import binomtest

from observer_gym.envs.ball_catcher import MISS_REASONS
from observer_gym.train.cli import main
from observer_gym.train.core.tasks.ball_catcher import (
    NOT_CAUGHT_REASONS,
    SUMMARY_ROWS,
    UNFINISHED,
    miss_reason,
    summarize,
)


def test_kf_measurements_run_catches_and_writes_results(tmp_path):
    out_dir = tmp_path / "run"
    code = main(
        [
            "run",
            "--env",
            "BallCatcher-v1",
            "--observer",
            "kf-measurements",
            "--controller",
            "intercept",
            "--episodes",
            "4",
            "--env-option",
            "camera_preset=synchronised",
            "--env-option",
            "latency_s=0.02",
            "--out",
            str(out_dir),
            "--no-progress",
        ]
    )
    assert code == 0
    results = json.loads((out_dir / "results.json").read_text())
    assert results["config"]["env_kwargs"] == {
        "obs_mode": "measurements",
        "camera_preset": "synchronised",
        "latency_s": 0.02,
    }
    assert results["config"]["env_config"]["latency_s"] == 0.02
    summary = results["summary"]
    assert set(summary) >= set(SUMMARY_ROWS)
    assert summary["catches"] == 4 and summary["catch_rate"] == 1.0
    assert summary["miss_reasons"] == dict.fromkeys(NOT_CAUGHT_REASONS, 0)
    for episode in results["episodes"]:
        assert episode["outcome"] == "caught" and episode["miss_reason"] is None
        assert episode["miss_distance_m"] < 0.005  # within the 5 mm a clean pass allows
        assert 0.0 < episode["position_rmse_m"] < 0.02  # from 0.1 s after the launch
    assert set(results["files"]) == {"plane.png", "estimate.png", "results.json"}
    assert (out_dir / "plane.png").stat().st_size > 10_000


def test_summary_interval_is_wilsons():
    episodes = [
        {
            "caught": i < 45,
            "outcome": "caught" if i < 45 else "missed",
            "miss_reason": None if i < 45 else "rim_touch",
            "miss_distance_m": 0.001 * i,
            "position_rmse_m": 0.0,
            "velocity_rmse_mps": 0.0,
            "box_travel_m": 0.1,
            "return": 1.0,
            "solver_failures": 0,
        }
        for i in range(50)
    ]
    summary = summarize(episodes)
    assert summary["catch_rate"] == pytest.approx(0.9)
    # Wilson's score interval for 45 / 50 at 95 %: 0.786 ... 0.957 (closed form).
    assert summary["catch_rate_low"] == pytest.approx(0.7864, abs=1e-3)
    assert summary["catch_rate_high"] == pytest.approx(0.9565, abs=1e-3)
    ci = binomtest(45, 50).proportion_ci(method="wilson")
    assert summary["catch_rate_low"] == pytest.approx(ci.low)
    assert summary["outcomes"] == {"caught": 45, "missed": 5}
    assert summary["miss_reasons"] == dict.fromkeys(NOT_CAUGHT_REASONS, 0) | {"rim_touch": 5}


def test_every_episode_not_caught_has_a_reason_and_the_summary_counts_them():
    reasons = [*MISS_REASONS, UNFINISHED]
    assert NOT_CAUGHT_REASONS == tuple(reasons)
    final_infos = [{"outcome": "caught", "caught": True}]  # a catch: no miss_reason key
    final_infos += [{"outcome": "missed", "caught": False, "miss_reason": r} for r in MISS_REASONS]
    final_infos += [{"outcome": "flying", "caught": False}]  # cut by the time limit or --steps
    assert [miss_reason(info) for info in final_infos] == [None, *reasons]

    base = {
        "miss_distance_m": None,
        "position_rmse_m": 0.0,
        "velocity_rmse_mps": 0.0,
        "box_travel_m": 0.1,
        "return": 0.0,
        "solver_failures": 0,
    }
    counts = {"rim_touch": 3, "bounced_off": 2, "unfinished": 1}
    episodes = [{**base, "caught": True, "outcome": "caught", "miss_reason": None}] * 4
    for reason, k in counts.items():
        outcome = "flying" if reason == UNFINISHED else "missed"
        episodes += [{**base, "caught": False, "outcome": outcome, "miss_reason": reason}] * k
    summary = summarize(episodes)
    assert summary["miss_reasons"] == {r: counts.get(r, 0) for r in reasons}
    assert list(summary["miss_reasons"]) == reasons  # every reason, in the documented order
    assert sum(summary["miss_reasons"].values()) == summary["episodes"] - summary["catches"]
    for reason in reasons:
        assert summary[f"misses_{reason}"] == counts.get(reason, 0)
        assert f"misses_{reason}" in SUMMARY_ROWS


def test_bad_env_option_is_rejected(capsys):
    with pytest.raises(SystemExit) as exc:
        main(
            [
                "run",
                "--env",
                "BallCatcher-v1",
                "--observer",
                "oracle",
                "--controller",
                "intercept",
                "--env-option",
                "no_equals_sign",
            ]
        )
    assert exc.value.code == 2
    assert "KEY=VALUE" in capsys.readouterr().err
