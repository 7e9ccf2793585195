"""``observer-gym run``: closed-loop episodes, their metrics, results.json, plots, the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import pytest

from observer_gym.train.cli import main
from observer_gym.train.core.systems import resolve_env_id
from observer_gym.train.core.tasks.ball_table import SUMMARY_ROWS
from observer_gym.train.experiments.episode import EpisodeSpec, run_episodes
from observer_gym.train.experiments.run import run_experiment
from observer_gym.train.reports.outputs import VERSIONED_PACKAGES

ENV_ID = "observer_gym/BallTable-v0"
START_10_CM = {"ball_pos_table_m": (0.1, 0.0), "ball_vel_table_mps": (0.0, 0.0)}
EPISODE_KEYS = {
    "episode",
    "seed",
    "steps",
    "duration_s",
    "terminated",
    "return",
    "start_distance_m",
    "mean_distance_m",
    "final_distance_m",
    "settling_time_s",
    "time_within_s",
    "effort_rms_rad",
    "position_rmse_m",
    "velocity_rmse_mps",
    "solver_failures",
}


def check_plot(path: Path) -> None:
    image = cv2.imread(str(path))
    assert image is not None, f"{path} is missing or not an image"
    assert image.shape[0] > 200 and image.shape[1] > 200


def check_outputs(out_dir: Path, results: dict, plots: set[str]) -> None:
    """results.json holds what run_experiment returned; no temp file; the plots exist."""
    assert json.loads((out_dir / "results.json").read_text()) == results
    assert not [p.name for p in out_dir.iterdir() if p.name.endswith(".tmp")]
    assert set(results["files"]) == plots | {"results.json"}
    for name in plots:
        check_plot(out_dir / name)


@pytest.fixture(scope="module")
def lqr_from_10_cm(tmp_path_factory) -> tuple[Path, dict]:
    out_dir = tmp_path_factory.mktemp("lqr")
    results = run_experiment(
        "BallTable-v0",
        "oracle",
        "lqr",
        2,
        7,
        out_dir,
        steps=150,
        progress=False,
        reset_options=START_10_CM,
    )
    return out_dir, results


def test_oracle_lqr_centres_the_ball_from_10_cm(lqr_from_10_cm):
    _, results = lqr_from_10_cm
    for episode in results["episodes"]:
        assert episode["steps"] == 150 and episode["duration_s"] == pytest.approx(3.0)
        assert episode["start_distance_m"] == pytest.approx(0.1, abs=1e-4)
        assert episode["final_distance_m"] < 0.01
        # It settles in under a second and stays in the band for the rest of the 3 s (it may
        # pass through the band once before, while overshooting).
        assert 0.3 < episode["settling_time_s"] < 1.5
        assert 3.0 - episode["settling_time_s"] - 1e-9 <= episode["time_within_s"] <= 3.0
        assert 0.0 < episode["effort_rms_rad"] <= 0.1 * 2**0.5  # within the tilt bound
        assert episode["position_rmse_m"] == 0.0 and episode["velocity_rmse_mps"] == 0.0
        assert episode["solver_failures"] == 0 and episode["terminated"] is False
    summary = results["summary"]
    assert summary["fraction_settled"] == 1.0 and summary["terminated"] == 0


def test_results_json_and_plots(lqr_from_10_cm):
    out_dir, results = lqr_from_10_cm
    check_outputs(out_dir, results, {"path.png", "error.png"})
    assert set(results) == {
        "config",
        "seed",
        "versions",
        "wall_time_s",
        "episodes",
        "summary",
        "consistency",
        "files",
    }
    assert results["consistency"] == {"nees_ratio": None, "band": None, "consistent": None}
    config = results["config"]
    assert config["env_id"] == ENV_ID
    assert config["env_kwargs"] == {"obs_mode": "state"}
    assert config["env_config"]["obs_mode"] == "state"
    assert (config["observer"], config["controller"], config["episodes"]) == ("oracle", "lqr", 2)
    assert (config["steps"], config["workers"], config["seed"]) == (150, 1, 7)
    assert len(config["controller_config"]["K"]) == 2  # the LQR gain, 2 x 6
    assert set(results["versions"]) == set(VERSIONED_PACKAGES)
    assert results["seed"] == 7
    assert [e["seed"] for e in results["episodes"]] == [7, 8]
    assert all(set(e) == EPISODE_KEYS for e in results["episodes"])
    assert set(results["summary"]) >= set(SUMMARY_ROWS)


@pytest.mark.parametrize("controller", ["mpc", "pid"])
def test_oracle_mpc_and_pid_bring_the_ball_in(controller, tmp_path):
    results = run_experiment(
        ENV_ID,
        "oracle",
        controller,
        2,
        0,
        tmp_path,
        steps=150,
        progress=False,
        reset_options=START_10_CM,
    )
    for episode in results["episodes"]:
        assert episode["terminated"] is False and episode["steps"] == 150
        assert episode["final_distance_m"] < 0.5 * episode["start_distance_m"]
        assert episode["solver_failures"] == 0
    if controller == "mpc":  # the MPC's first move is the LQR's: it settles as fast
        assert all(e["final_distance_m"] < 0.01 for e in results["episodes"])
        assert results["config"]["controller_config"]["horizon"] >= 1


def test_random_starts_use_seed_plus_episode(tmp_path):
    results = run_experiment(ENV_ID, "oracle", "pid", 3, 4, tmp_path, steps=5, progress=False)
    episodes = results["episodes"]
    assert [e["seed"] for e in episodes] == [4, 5, 6]
    starts_m = [e["start_distance_m"] for e in episodes]
    assert len(set(starts_m)) == 3 and max(starts_m) <= 0.1  # the 0.1 m start disc
    again = run_experiment(ENV_ID, "oracle", "pid", 1, 5, tmp_path, steps=5, progress=False)
    assert again["episodes"][0] == {**episodes[1], "episode": 0}


def test_kf_measurements_lqr_episode(tmp_path):
    results = run_experiment(
        ENV_ID,
        "kf-measurements",
        "lqr",
        1,
        0,
        tmp_path,
        steps=150,
        progress=False,
        reset_options=START_10_CM,
    )
    (episode,) = results["episodes"]
    assert episode["final_distance_m"] < 0.01
    # Perfect-detector pixels: the filter is off by well under a millimetre.
    assert 0.0 < episode["position_rmse_m"] < 1e-3
    assert 0.0 < episode["velocity_rmse_mps"] < 0.05
    assert results["config"]["env_kwargs"] == {"obs_mode": "measurements"}
    check_outputs(tmp_path, results, {"path.png", "error.png", "estimate.png"})


# worker processes (6 s idle): slow; test_outside_entries.py's one worker against two stays
@pytest.mark.slow
def test_two_workers_give_the_results_of_one(tmp_path):
    def run(workers: int) -> dict:
        return run_experiment(
            ENV_ID,
            "kf-measurements",
            "mpc",
            2,
            3,
            tmp_path / f"w{workers}",
            steps=50,
            workers=workers,
            progress=False,
        )

    one, two = run(1), run(2)
    assert two["config"]["workers"] == 2
    assert one["episodes"] == two["episodes"]
    assert one["summary"] == two["summary"]


@pytest.mark.slow  # starts worker processes: 3.3 s (load ~2)
def test_a_failing_episode_in_a_worker_raises_naming_the_episode():
    good = EpisodeSpec.of(ENV_ID, "oracle", "lqr", seed=0, max_steps=5)
    bad = EpisodeSpec.of(ENV_ID, "oracle", "lqr", seed=1, max_steps=5, env_kwargs={"bogus": 1})
    with pytest.raises(ValueError, match="bogus") as raised:
        run_episodes([good, bad, good, good], workers=2, progress=False)
    assert any("seed=1" in note for note in raised.value.__notes__)


def test_bad_arguments_raise(tmp_path):
    with pytest.raises(ValueError, match="BallTable-v0"):
        run_experiment("CartPole-v1", "oracle", "lqr", 1, 0, tmp_path)
    with pytest.raises(ValueError, match="observer"):
        run_experiment(ENV_ID, "no-such-observer", "lqr", 1, 0, tmp_path)
    with pytest.raises(ValueError, match="controller"):
        run_experiment(ENV_ID, "oracle", "rl", 1, 0, tmp_path)
    with pytest.raises(ValueError, match="episodes"):
        run_experiment(ENV_ID, "oracle", "lqr", 0, 0, tmp_path)
    with pytest.raises(ValueError, match="seed"):
        run_experiment(ENV_ID, "oracle", "lqr", 1, -1, tmp_path)
    assert resolve_env_id("BallTable-v0") == resolve_env_id(ENV_ID) == ENV_ID


def test_cli_run_from_pixels_writes_results(tmp_path, capsys):
    out_dir = tmp_path / "run"
    argv = ["run", "--env", ENV_ID, "--observer", "kf", "--controller", "lqr"]
    argv += ["--episodes", "1", "--seed", "2", "--steps", "25", "--no-progress"]
    assert main([*argv, "--out", str(out_dir)]) == 0
    results = json.loads((out_dir / "results.json").read_text())
    check_outputs(out_dir, results, {"path.png", "error.png", "estimate.png"})
    assert results["config"]["cli_args"]["observer"] == "kf"
    assert results["config"]["env_kwargs"] == {"obs_mode": "rgb"}
    assert results["episodes"][0]["steps"] == 25
    assert 0.0 < results["episodes"][0]["position_rmse_m"] < 0.005
    printed = capsys.readouterr().out
    for label, *_ in SUMMARY_ROWS.values():
        assert label in printed
    assert str(out_dir) in printed


def test_cli_rejects_an_unknown_env(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["run", "--env", "BallJuggler-v0", "--observer", "oracle", "--controller", "lqr"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "unknown env 'BallJuggler-v0'" in err and "BallCatcher-v1" in err


def test_a_controller_made_for_another_env_raises(tmp_path):
    with pytest.raises(ValueError, match="BallTable-v0 env"):
        run_experiment("BallCatcher-v1", "oracle", "lqr", 1, 0, tmp_path, progress=False)


def test_cli_names_what_an_observer_can_be(capsys):
    assert main(["run", "--observer", "no-such-observer", "--controller", "lqr"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "unknown observer 'no-such-observer'" in err
    assert "raw-measurements" in err and "an import path package.module:factory" in err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--observer", "oracle", "--controller", "rl"], "neither a controller"),
        (["--observer", "oracle", "--controller", "a2c:runs/x"], "neither a controller"),
        (["--observer", "oracle", "--controller", "lqr", "--episodes", "0"], "must be an"),
        (["--observer", "oracle", "--controller", "lqr", "--workers", "x"], "not an integer"),
        (["--observer", "oracle", "--controller", "lqr", "--seed", "-1"], "must be an"),
        (["--controller", "lqr"], "--observer"),
    ],
)
def test_cli_rejects_bad_values(argv, message, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["run", *argv])
    assert exc.value.code == 2
    assert message in capsys.readouterr().err
