"""``observer-gym record``: episodes kept as a Minari dataset, loaded back with Minari, the
truth and the estimate in its infos those of a run without recording, replayable from the
recorded seed; and the refusals (an existing folder, unknown names, no minari)."""

from __future__ import annotations

import os
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest

pytest.importorskip("minari")
pytest.importorskip("jax")
pytest.importorskip("h5py")

import minari

from observer_gym.train.cli import main
from observer_gym.train.experiments.episode import EpisodeSpec, run_episode
from observer_gym.train.experiments.record import record_experiment
from observer_gym.train.reports.dataset import (
    dataset_id_for,
    episodes_of,
    read_recording,
)

ENV, OBSERVER, CONTROLLER = "BallTable-v0", "kf-measurements", "lqr"
SEED, EPISODES, STEPS = 7, 3, 12
# a frame latency, so that capture and delivery times differ (two steps of 0.02 s)
ENV_KWARGS = {"latency_s": 0.04}
DATASET_ID = "observer_gym/ball_table-kf-measurements-lqr-v0"


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    out = tmp_path_factory.mktemp("record") / "dataset"
    record = record_experiment(
        ENV, OBSERVER, CONTROLLER, EPISODES, SEED, out, steps=STEPS, progress=False,
        env_kwargs=ENV_KWARGS,
    )  # fmt: skip
    return out, record


@pytest.fixture
def loaded(recorded, monkeypatch):
    out, _ = recorded
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(out))
    return minari.load_dataset(DATASET_ID)


def fresh_run(seed: int) -> dict:
    """The same episode run by ``observer-gym run``'s loop, without any recording."""
    spec = EpisodeSpec.of(
        ENV, OBSERVER, CONTROLLER, seed, max_steps=STEPS, env_kwargs=ENV_KWARGS
    )  # fmt: skip
    return run_episode(spec)


def test_the_dataset_id_is_minaris_and_names_the_pair():
    assert dataset_id_for("ball_table", OBSERVER, CONTROLLER) == DATASET_ID
    # a trained agent's ':' and '/' are not in a Minari id
    assert (
        dataset_id_for("ball_table", "kf", "ppo:runs/x")
        == "observer_gym/ball_table-kf-ppo_runs_x-v0"
    )


def test_minari_loads_the_episodes_with_their_lengths(recorded, loaded):
    out, record = recorded
    assert record["dataset_id"] == DATASET_ID
    assert loaded.total_episodes == EPISODES and loaded.total_steps == EPISODES * STEPS
    for episode in loaded.iterate_episodes():
        assert len(episode) == STEPS
        # the measurements the observer was given, not its estimate
        assert sorted(episode.observations) == ["ball_px", "detected", "table_corners_px"]
        assert episode.observations["ball_px"].shape == (STEPS + 1, 3)
        assert episode.actions.shape == (STEPS, 2)
        # capped by --steps: Minari marks the last step truncated
        assert not episode.terminations.any() and episode.truncations.tolist() == [False] * (
            STEPS - 1
        ) + [True]
    # nothing but the dataset and record.json, and no staging folder beside it
    assert sorted(p.name for p in out.iterdir()) == ["observer_gym", "record.json"]
    assert [p.name for p in out.parent.iterdir()] == ["dataset"]


def test_the_metadata_names_the_env_options_observer_controller_and_version(loaded):
    mine = loaded.storage.metadata["observer_gym"]
    config = mine["config"]
    assert config["env_id"] == "observer_gym/BallTable-v0"
    assert config["env_kwargs"] == {"obs_mode": "measurements", **ENV_KWARGS}
    assert config["env_config"]["latency_s"] == ENV_KWARGS["latency_s"]
    assert (config["observer"], config["controller"]) == (OBSERVER, CONTROLLER)
    assert config["controller_config"]["name"] == CONTROLLER
    assert (config["seed"], config["episodes"], config["steps"]) == (SEED, EPISODES, STEPS)
    assert mine["versions"]["observer-gym"] not in ("", "not installed")
    assert mine["versions"]["minari"] == minari.__version__
    assert [e["seed"] for e in mine["episodes"]] == [SEED, SEED + 1, SEED + 2]


def test_the_truth_and_estimate_in_the_infos_are_a_fresh_runs(loaded):
    episodes = episodes_of(loaded)
    assert [e.seed for e in episodes] == [SEED, SEED + 1, SEED + 2]
    for episode in episodes:
        fresh = fresh_run(episode.seed)
        np.testing.assert_array_equal(episode.state, fresh["state"])
        np.testing.assert_array_equal(episode.estimate_mean, fresh["estimate"])
        np.testing.assert_array_equal(
            np.sqrt(np.diagonal(episode.estimate_covariance, axis1=1, axis2=2)),
            fresh["estimate_std"],
        )
        np.testing.assert_array_equal(episode.time_s, fresh["time_s"])
        np.testing.assert_allclose(episode.actions, fresh["actions"], rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(episode.rewards, fresh["rewards"], rtol=1e-6)
    # and the episodes differ from one another (the seeds matter)
    assert not np.array_equal(episodes[0].state, episodes[1].state)


def test_the_frame_times_show_the_latency(recorded):
    out, _ = recorded
    for episode in read_recording(out):
        count = episode.infos["frame_count"][:, 0]
        capture = episode.infos["frame_capture_time_s"][:, 0]
        delivery = episode.infos["frame_delivery_time_s"][:, 0]
        delivered = count > 0
        assert delivered.sum() >= STEPS // 2  # a 50 Hz camera, 50 Hz steps, after the latency
        np.testing.assert_allclose(delivery[delivered] - capture[delivered], 0.04, atol=1e-9)
        np.testing.assert_allclose(delivery[delivered], episode.time_s[delivered], atol=1e-9)
        assert np.isnan(capture[~delivered]).all()
        K = episode.infos["K_nominal"][delivered]
        assert np.allclose(K[:, 0, 0, 0], K[0, 0, 0, 0]) and K[0, 0, 2, 2] == 1.0
        # no calibration error: the world's camera is the nominal one
        np.testing.assert_array_equal(K, episode.infos["K_true"][delivered])


def replayed(obs_mode: str, env_kwargs: dict, seed: int, actions: np.ndarray) -> tuple:
    """The observations and true states of the env in ``obs_mode`` reset with ``seed`` and
    stepped with ``actions``, each stacked over the steps."""
    env = gym.make(f"observer_gym/{ENV}", obs_mode=obs_mode, **env_kwargs)
    try:
        obs, info = env.reset(seed=seed)
        observations, states = [obs], [info["state"]]
        for action in actions:
            obs, _, _, _, info = env.step(action)
            observations.append(obs)
            states.append(info["state"])
    finally:
        env.close()
    if isinstance(observations[0], dict):
        return {k: np.array([o[k] for o in observations]) for k in observations[0]}, states
    return np.array(observations), np.array(states)


def test_replaying_the_actions_from_the_recorded_seed_gives_the_observations(recorded):
    out, _ = recorded
    for episode in read_recording(out):
        observations, states = replayed("measurements", ENV_KWARGS, episode.seed, episode.actions)
        assert sorted(observations) == sorted(episode.observations)
        for key, value in observations.items():
            np.testing.assert_array_equal(value, episode.observations[key])
        np.testing.assert_array_equal(states, episode.state)


@pytest.mark.slow  # rendered frames: 3.2 s at load 2; the measurements' replay stays
def test_camera_frames_are_recorded_losslessly_and_replay(tmp_path):
    out = tmp_path / "frames"
    record_experiment(ENV, "kf", CONTROLLER, 1, 3, out, steps=4, progress=False)
    (episode,) = read_recording(out)
    assert episode.observations.shape == (5, 240, 320, 3)
    assert episode.observations.dtype == np.uint8
    observations, _ = replayed("rgb", {}, 3, episode.actions)
    np.testing.assert_array_equal(observations, episode.observations)  # no JPEG loss
    assert episode.estimate_mean.shape == (5, 8)  # the estimate is in the infos


def test_the_python_function_records_the_seeds_given(tmp_path):
    import observer_gym

    result = observer_gym.record(
        ENV, OBSERVER, CONTROLLER, seeds=[4, 5], steps=2, out_dir=tmp_path / "r"
    )
    assert result.dataset_id == DATASET_ID and result.out_dir == tmp_path / "r"
    assert [(e["seed"], e["steps"]) for e in result.episodes] == [(4, 2), (5, 2)]
    assert [e.seed for e in read_recording(result.out_dir)] == [4, 5]


def one_line_error(capsys, argv: list[str]) -> tuple[int, str]:
    code = main(argv)
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    return code, err


ARGV = ["record", "--observer", OBSERVER, "--controller", CONTROLLER, "--episodes", "1"]


def test_an_existing_folder_is_refused_and_left_as_it_was(tmp_path, capsys):
    out = tmp_path / "there"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    code, err = one_line_error(capsys, [*ARGV, "--steps", "2", "--out", str(out)])
    assert code == 2
    assert err.startswith("observer-gym record: error: ") and f"{out} exists" in err
    assert [p.name for p in out.iterdir()] == ["keep.txt"]


def test_an_unknown_observer_is_refused_naming_the_allowed_ones(tmp_path, capsys):
    argv = ["record", "--observer", "nope", "--controller", CONTROLLER]
    code, err = one_line_error(capsys, [*argv, "--out", str(tmp_path / "r")])
    assert code == 2 and "unknown observer 'nope'" in err and "kf-measurements" in err
    assert not (tmp_path / "r").exists()


def test_an_unknown_controller_is_refused_naming_the_allowed_ones(tmp_path, capsys):
    argv = ["record", "--observer", OBSERVER, "--controller", "nope"]
    with pytest.raises(SystemExit) as exited:
        main([*argv, "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert exited.value.code == 2 and len(err.strip().splitlines()) == 1
    assert "'nope' is neither a controller (lqr" in err
    assert not (tmp_path / "r").exists()


def test_a_relative_out_folder_is_written_there(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main([*ARGV, "--steps", "2", "--out", "rel", "--no-progress"]) == 0
    assert "dataset observer_gym/" in capsys.readouterr().out
    assert [e.seed for e in read_recording(tmp_path / "rel")] == [0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rel"]


def test_a_killed_recordings_staging_is_removed_by_the_next(tmp_path, capsys):
    finished = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                              capture_output=True, text=True, check=True)  # fmt: skip
    dead_pid = int(finished.stdout)
    left = tmp_path / f".r.tmp-{dead_pid}"
    (left / "observer_gym").mkdir(parents=True)
    alive = tmp_path / f".r.tmp-{os.getppid()}"  # a running process's: kept
    alive.mkdir()
    assert main([*ARGV, "--steps", "2", "--out", str(tmp_path / "r"), "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert f"warning: removed {left}, left by a recording into" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["r", alive.name])


def test_help_names_the_command(capsys):
    with pytest.raises(SystemExit) as exited:
        main(["record", "--help"])
    assert exited.value.code == 0 and "Minari dataset" in capsys.readouterr().out


def test_an_interrupted_recording_leaves_no_folder(tmp_path, capsys, monkeypatch):
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(minari.DataCollector, "create_dataset", interrupted)
    code = main([*ARGV, "--steps", "3", "--out", str(tmp_path / "r"), "--no-progress"])
    assert code == 130 and "interrupted" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []  # neither the folder nor its staging
