"""``--rerun DIR`` on ``compare``, ``sweep`` and ``benchmark``: one ``.rrd`` per chosen
episode of every pair (cell, level), named as ``--video`` names its files, read back with
rerun-sdk's own reader (``rerun.chunk.RrdReader``); the episodes' numbers the same as
without; the refusals one line before anything runs."""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import sys
from pathlib import Path

import pytest

from observer_gym.envs import system_for_id
from observer_gym.train.cli import main
from observer_gym.train.core.observer_env import make_env, resolve_observer
from observer_gym.train.experiments.episode import build_controller
from observer_gym.train.experiments.request import resolve_controller

TABLE = "observer_gym/BallTable-v0"
STEPS = 6
# compare, sweep and benchmark, each asked for a recording of one episode
COMMANDS = {
    "compare": ["compare", "--observers", "kf", "--controllers", "lqr"],
    "sweep": ["sweep", "--vary", "latency_s=0.0", "--observers", "kf", "--controllers", "lqr"],
    "benchmark": ["benchmark", "--env", "BallTable-v0", "--observer", "kf", "--controller", "lqr"],
}
COMMANDS = {name: [*argv, "--episodes", "1"] for name, argv in COMMANDS.items()}


def delivered_images(observer: str, controller: str, seed: int, steps: int) -> int:
    """The camera images the observer received in the episode (the reset's frames and
    each step's), from a run of it without any recording."""
    system = system_for_id(TABLE)
    env = make_env(system, resolve_observer(system, observer))
    try:
        built = build_controller(resolve_controller(system, controller), env, system)
        built.reset()
        observe = getattr(built, "observe_info", lambda info: None)
        obs, info = env.reset(seed=seed)
        observe(info)
        count = len(info["frames"])
        for _ in range(steps):
            action, _ = built.predict(obs)
            obs, _, terminated, truncated, info = env.step(action)
            observe(info)
            count += len(info["frames"])
            if terminated or truncated:
                break
        return count
    finally:
        env.close()


def logged_images(reader) -> int:
    """The images a recording holds (``EncodedImage`` rows of camera 0's true frame)."""
    count = 0
    for chunk in reader.stream().to_chunks():
        if chunk.entity_path != "/world/camera0/true/image":
            continue
        batch = chunk.to_record_batch()
        if "EncodedImage:blob" in batch.schema.names:
            count += batch.num_rows - batch.column("EncodedImage:blob").null_count
    return count


def test_the_chosen_episodes_of_each_group_get_the_videos_names_with_rrd(tmp_path):
    """Two pairs (groups) of three episodes, episodes 0 and 2 chosen, a cell's prefix:
    each chosen episode's recording is its video's stem + .rrd in the folder; the others
    get none."""
    pytest.importorskip("rerun")
    from observer_gym.train.experiments.episode import EpisodeSpec
    from observer_gym.train.experiments.videos import (
        plan_reruns,
        plan_videos_for,
        with_reruns,
        with_videos,
    )

    specs = [
        EpisodeSpec.of(TABLE, observer, "lqr", seed)
        for observer in ("kf", "raw")
        for seed in (7, 8, 9)
    ]
    prefix = "latency_s-0.04__"
    reruns = plan_reruns(tmp_path / "rrd", [0, 2], 3)
    videos = plan_videos_for(tmp_path / "v", [0, 2], 3, [spec.observer for spec in specs[::3]])
    recorded = with_reruns(specs, reruns, 3, prefix)
    filmed = with_videos(specs, videos, 3, prefix)
    paths = [None if s.rerun is None else Path(s.rerun.path) for s in recorded]
    assert paths == [
        tmp_path / "rrd" / "latency_s-0.04__BallTable-v0_kf_lqr_episode0_seed7.rrd",
        None,
        tmp_path / "rrd" / "latency_s-0.04__BallTable-v0_kf_lqr_episode2_seed9.rrd",
        tmp_path / "rrd" / "latency_s-0.04__BallTable-v0_raw_lqr_episode0_seed7.rrd",
        None,
        tmp_path / "rrd" / "latency_s-0.04__BallTable-v0_raw_lqr_episode2_seed9.rrd",
    ]
    for rec, film in zip(recorded, filmed, strict=True):
        assert (rec.rerun is None) == (film.video is None)
        if rec.rerun is not None:
            assert rec.rerun.name == film.video.stem == Path(rec.rerun.path).stem
    # the episodes themselves are the specs given, the recording aside
    assert [dataclasses.replace(s, rerun=None) for s in recorded] == specs


def one_line_error(capsys, argv: list[str]) -> tuple[int, str]:
    code = main(argv)
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    return code, err


@pytest.mark.slow  # two comparisons of two pixel pairs (one in 2 processes), two replays
def test_compare_writes_one_recording_per_pair_named_as_the_videos_and_changes_nothing(
    tmp_path, capsys
):
    pytest.importorskip("rerun")
    from rerun.chunk import RrdReader

    argv = ["compare", "--observers", "kf,raw", "--controllers", "lqr", "--seeds", "4"]
    argv += ["--steps", str(STEPS), "--no-progress"]
    assert main([*argv, "--out", str(tmp_path / "plain")]) == 0
    folder = tmp_path / "rrd"
    recording = ["--rerun", str(folder), "--workers", "2"]  # written in worker processes
    assert main([*argv, "--out", str(tmp_path / "recorded"), *recording]) == 0
    capsys.readouterr()
    plain = json.loads((tmp_path / "plain" / "results.json").read_text())
    recorded = json.loads((tmp_path / "recorded" / "results.json").read_text())
    assert [p["episodes"] for p in plain["pairs"]] == [p["episodes"] for p in recorded["pairs"]]
    names = sorted(p.name for p in folder.iterdir())  # no temps left beside them
    assert names == [
        "BallTable-v0_kf_lqr_episode0_seed4.rrd",
        "BallTable-v0_raw_lqr_episode0_seed4.rrd",
    ]
    for observer in ("kf", "raw"):
        path = folder / f"BallTable-v0_{observer}_lqr_episode0_seed4.rrd"
        assert logged_images(RrdReader(path)) == delivered_images(observer, "lqr", 4, STEPS) > 0


@pytest.mark.slow  # a sweep of two cells, and again (resumed)
def test_a_sweep_names_each_cells_recordings_by_its_point_and_a_resume_records_none(
    tmp_path, capsys
):
    pytest.importorskip("rerun")
    argv = ["sweep", "--vary", "latency_s=0.0,0.04", "--observers", "kf-measurements"]
    argv += ["--controllers", "lqr", "--episodes", "2", "--steps", "5", "--no-progress"]
    argv += ["--out", str(tmp_path / "sweep")]
    assert main([*argv, "--rerun", str(tmp_path / "rrd"), "--rerun-episodes", "1"]) == 0
    assert sorted(p.name for p in (tmp_path / "rrd").iterdir()) == [
        "latency_s-0.04__BallTable-v0_kf-measurements_lqr_episode1_seed1.rrd",
        "latency_s-0.0__BallTable-v0_kf-measurements_lqr_episode1_seed1.rrd",
    ]
    # the cells are reused, not run again: no recording
    assert main([*argv, "--rerun", str(tmp_path / "again")]) == 0
    capsys.readouterr()
    assert list((tmp_path / "again").iterdir()) == []


@pytest.mark.slow  # two benchmarks of three full-length levels (27 s at load 5)
def test_a_benchmark_names_each_levels_recording_by_the_level_and_scores_the_same(tmp_path, capsys):
    pytest.importorskip("rerun")
    argv = ["benchmark", "--env", "BallTable-v0", "--observer", "kf-measurements"]
    argv += ["--controller", "lqr", "--episodes", "1", "--no-progress"]
    assert main([*argv, "--out", str(tmp_path / "plain")]) == 0
    assert main([*argv, "--out", str(tmp_path / "recorded"), "--rerun", str(tmp_path / "rrd")]) == 0
    capsys.readouterr()
    names = sorted(p.name for p in (tmp_path / "rrd").iterdir())
    levels = sorted(p.stem for p in (tmp_path / "plain" / "levels").glob("*.json"))
    assert [name.split("__")[0] for name in names] == levels
    for name in names:
        assert name.split("__")[1].startswith("BallTable-v0_kf-measurements_lqr_episode0_seed")
    for level in levels:
        plain = json.loads((tmp_path / "plain" / "levels" / f"{level}.json").read_text())
        recorded = json.loads((tmp_path / "recorded" / "levels" / f"{level}.json").read_text())
        assert (plain["seeds"], plain["values"]) == (recorded["seeds"], recorded["values"])
        assert (
            f"{level}__BallTable-v0_kf-measurements_lqr_episode0_seed{plain['seeds'][0]}.rrd"
            in names
        )


@pytest.mark.slow  # starts Ray
def test_ray_tasks_write_the_recordings(tmp_path):
    pytest.importorskip("rerun")
    pytest.importorskip("ray")
    from rerun.chunk import RrdReader

    import observer_gym

    observer_gym.compare(
        "BallTable-v0", ["oracle", "kf-measurements"], "lqr", seeds=[3], steps=5,
        out_dir=tmp_path / "out", backend="ray", rerun_dir=tmp_path / "rrd",
    )  # fmt: skip
    names = sorted(p.name for p in (tmp_path / "rrd").iterdir())
    assert names == [
        "BallTable-v0_kf-measurements_lqr_episode0_seed3.rrd",
        "BallTable-v0_oracle_lqr_episode0_seed3.rrd",
    ]
    for name in names:  # whole: the footer reads back; the truth at the reset and 5 steps
        chunks = RrdReader(tmp_path / "rrd" / name).stream().to_chunks()
        truths = sum(c.num_rows for c in chunks if c.entity_path == "/world/ball/truth")
        assert truths == 6


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_without_the_extra_each_command_names_the_install_line(
    tmp_path, capsys, monkeypatch, command
):
    real = importlib.util.find_spec

    def find_spec(name, *args, **kwargs):
        return None if name == "rerun" else real(name, *args, **kwargs)

    monkeypatch.delitem(sys.modules, "rerun", raising=False)
    monkeypatch.setattr(importlib.util, "find_spec", find_spec)
    argv = [*COMMANDS[command], "--out", str(tmp_path / "out"), "--rerun", str(tmp_path / "rrd")]
    code, err = one_line_error(capsys, argv)
    assert code == 2
    assert "--rerun needs rerun-sdk, which is not installed: " in err
    assert "pip install 'observer-gym[rerun]'" in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_a_folder_that_cannot_be_written_is_refused_before_any_episode(tmp_path, capsys, command):
    pytest.importorskip("rerun")
    blocker = tmp_path / "file"
    blocker.write_text("")
    argv = [*COMMANDS[command], "--out", str(tmp_path / "out"), "--rerun", str(blocker / "rrd")]
    code, err = one_line_error(capsys, argv)
    assert code == 1 and f"cannot write rerun recordings into {blocker / 'rrd'}: " in err
    assert [p.name for p in tmp_path.iterdir()] == ["file"]


BAD = [  # (options after the command's, what the line says)
    (["--rerun-episodes", "0"], "--rerun-episodes needs --rerun DIR"),
    (["--rerun", "{tmp}/rrd", "--rerun-episodes", "0,1"], "rerun episodes [1] are outside"),
    (["--rerun", "{tmp}/x.rrd"], "--rerun takes a folder here (one .rrd per recorded episode)"),
]


@pytest.mark.parametrize(("options", "says"), BAD)
@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_bad_rerun_options_are_one_line_and_write_nothing(tmp_path, capsys, command, options, says):
    pytest.importorskip("rerun")
    options = [o.replace("{tmp}", str(tmp_path)) for o in options]
    code, err = one_line_error(
        capsys, [*COMMANDS[command], "--out", str(tmp_path / "out"), *options]
    )
    assert code == 2 and says in err
    assert list(tmp_path.iterdir()) == []


def test_rerun_turned_off_in_the_environment_is_refused_before_any_episode(
    tmp_path, capsys, monkeypatch
):
    pytest.importorskip("rerun")
    monkeypatch.setenv("RERUN", "off")
    argv = [*COMMANDS["compare"], "--out", str(tmp_path / "out"), "--rerun", str(tmp_path / "r")]
    code, err = one_line_error(capsys, argv)
    assert code == 2 and "RERUN=off" in err
    assert list(tmp_path.iterdir()) == []
