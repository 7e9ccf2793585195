"""``observer-gym sweep``: the grid, the outputs and their numbers, the pairing of cells
(and that a sensor option leaves the world's draws alone), resuming, Ray, and mistakes."""

from __future__ import annotations

import csv
import dataclasses
import json
import os
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import gymnasium as gym
import numpy as np
import pytest
from scipy import stats

from observer_gym.envs import system_for_id
from observer_gym.train.cli import build_parser, main
from observer_gym.train.core.tasks.ball_table import COMPARE_METRICS
from observer_gym.train.experiments import sweep
from observer_gym.train.experiments.sweep import SweepWarning, run_sweep
from observer_gym.train.experiments.sweep_grid import check_grid, world_draw_notes
from observer_gym.train.experiments.sweep_plan import check_sweep

CLI = [sys.executable, "-m", "observer_gym.train.cli"]
KEY = "measurement_noise_px"  # a sensor option: it changes what kf-measurements sees only
VALUES = [0.0, 2.0]
OBSERVERS = ["oracle", "kf-measurements"]
CONTROLLERS = ["lqr", "pid"]
EPISODES, SEED, STEPS = 3, 5, 30
FIXED = {"push_rate_hz": 3.0}  # pushes: the world's draws that must not change with KEY
PRIMARY, SECOND = "mean_distance_m", "final_distance_m"
OUTPUTS = ("results.json", "episodes.csv", "table.md")
ARGS = {
    "env_id": "BallTable-v0",
    "vary": {KEY: VALUES},
    "observers": OBSERVERS,
    "controllers": CONTROLLERS,
    "episodes": EPISODES,
    "seed": SEED,
    "steps": STEPS,
    "env_kwargs": FIXED,
    "progress": False,
}
ARGV = [
    "sweep", "--vary", f"{KEY}=0,2", "--observers", ",".join(OBSERVERS), "--controllers",
    ",".join(CONTROLLERS), "--episodes", str(EPISODES), "--seed", str(SEED), "--steps",
    str(STEPS), "--env-option", "push_rate_hz=3.0", "--no-progress",
]  # fmt: skip


@pytest.fixture(scope="module")
def swept(tmp_path_factory) -> tuple[Path, sweep.SweepResult]:
    """The 2 x 2 x 2 sweep, uninterrupted."""
    out_dir = tmp_path_factory.mktemp("sweep") / "out"
    return out_dir, run_sweep(**ARGS, out_dir=out_dir)


def table_rows(markdown: str) -> list[list[str]]:
    lines = [line for line in markdown.splitlines() if line.startswith("|")]
    return [[c.strip() for c in line.strip("|").split("|")] for line in lines if "---" not in line]


def csv_rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


# --- outputs ---------------------------------------------------------------------------------
def test_a_2x2x2_sweep_writes_its_outputs_with_the_episodes_numbers(swept):
    out_dir, result = swept
    assert (result.cells_run, result.cells_reused) == (8, 0)
    assert json.loads((out_dir / "results.json").read_text()) == result.results
    assert result.files == ["table.md", "episodes.csv", f"{KEY}.png", "results.json"]
    assert len(list((out_dir / "cells").glob("*.json"))) == 8
    assert not [p for p in out_dir.rglob(".*") if p.is_file()]  # no temp, no marker left
    image = cv2.imread(str(out_dir / f"{KEY}.png"))
    assert image is not None and image.shape[0] > 300 and image.shape[1] > 600
    timing = json.loads((out_dir / "timing.json").read_text())
    assert timing["episodes_run"] == 8 * EPISODES and timing["episode_time_s_sum"] > 0

    rows = csv_rows(out_dir / "episodes.csv")
    assert len(rows) == 8 * EPISODES
    assert list(rows[0])[:5] == [KEY, "observer", "controller", "episode", "seed"]
    header, *table = table_rows((out_dir / "table.md").read_text())
    assert header[:3] == [KEY, "observer", "controller"] and len(table) == 8
    for row in table:
        episodes = [
            r
            for r in rows
            if (float(r[KEY]), r["observer"], r["controller"]) == (float(row[0]), row[1], row[2])
        ]
        assert [int(r["seed"]) for r in episodes] == list(range(SEED, SEED + EPISODES))
        for column, metric in ((3, PRIMARY), (4, SECOND)):
            values = np.array([float(r[metric]) for r in episodes])
            _, _, scale, digits, _ = COMPARE_METRICS[metric]
            half = stats.t.ppf(0.975, len(values) - 1) * stats.sem(values)
            assert row[column] == f"{values.mean() * scale:.{digits}f} ± {half * scale:.{digits}f}"


def test_the_command_line_in_the_results_repeats_the_sweep(swept, tmp_path):
    out_dir, result = swept
    command = result.results["config"]["command"]
    assert (out_dir / "table.md").read_text().splitlines()[0] == f"`{command}`"
    args = build_parser().parse_args([*shlex.split(command)[1:], "--out", str(tmp_path / "x")])
    plan = check_sweep(
        args.env, args.vary, args.observers, args.controllers, args.episodes, args.seed,
        steps=args.steps, env_kwargs=dict(args.env_option), second_metric=args.second_metric,
    )  # fmt: skip
    assert plan.arguments() == json.loads((out_dir / "sweep.json").read_text())["arguments"]


# --- pairing ---------------------------------------------------------------------------------
def test_cells_are_paired_and_a_sensor_option_leaves_the_world_alone(swept):
    _, result = swept
    results = result.results
    assert results["starts_match"] and results["starts_match_across_grid"]
    cells = {(c["point"][KEY], c["observer"], c["controller"]): c for c in results["cells"]}
    by_cell: dict[tuple, list[dict]] = {}
    for row in results["episodes"]:
        by_cell.setdefault((row[KEY], row["observer"], row["controller"]), []).append(row)
    assert set(by_cell) == set(cells)
    for rows in by_cell.values():
        assert [r["seed"] for r in rows] == list(range(SEED, SEED + EPISODES))
    for controller in CONTROLLERS:
        # The oracle does not see the pixel noise: with the same pushes, the same episodes.
        oracle = [by_cell[v, "oracle", controller] for v in VALUES]
        assert [[r[PRIMARY] for r in rows] for rows in oracle] == [
            [r[PRIMARY] for r in oracle[0]]
        ] * 2
        assert cells[VALUES[1], "oracle", controller]["vs_reference"]["mean"] == 0.0
        # The filter does.
        filtered = [[r[PRIMARY] for r in by_cell[v, "kf-measurements", controller]] for v in VALUES]
        assert filtered[0] != filtered[1]
        assert cells[VALUES[0], "kf-measurements", controller]["vs_reference"] is None


def _world(env_id: str, steps: int, **options) -> list[np.ndarray]:
    """What the world drew over ``steps`` steps of zero action from seed 11, and over the
    next episode, reset without a seed (the env's own generator goes on): BallTable's
    state and pushes, TargetFollower's target position and occlusions, BallCatcher's
    state and throw; one array per episode."""
    env = gym.make(env_id, **options)
    try:
        episodes = []
        for seed in (11, None):
            _, info = env.reset(seed=seed)
            drawn = []
            for _ in range(steps):
                drawn.append(_drawn(info))
                *_, terminated, _, info = env.step(np.zeros(env.action_space.shape))
                if terminated:
                    break
            episodes.append(np.array(drawn))
        return episodes
    finally:
        env.close()


def _drawn(info: dict) -> np.ndarray:
    if "throw" in info:
        return np.r_[info["state"], info["throw"]["launch_vel_world"]]
    if "target_pos_world" in info:  # its state is the target's image: camera-made
        return np.r_[info["target_pos_world"], info["occluded"]]
    push = info.get("push_impulse_ns")
    return np.r_[info["state"], np.zeros(3) if push is None else push]


# The worlds with their disturbances on: BallTable's pushes and occluder, TargetFollower's
# pushes and occluder walks (BallCatcher's throw is its only draw).
WORLDS = {
    "observer_gym/BallTable-v0": {"push_rate_hz": 5.0, "occluder_rate_hz": 1.0},
    "observer_gym/BallCatcher-v1": {"camera_preset": "random_offsets"},
    "observer_gym/TargetFollower-v0": {"push_rate_hz": 1.0, "occluder_rate_hz": 0.5},
}
# A value other than the default for every sensor option (envs/sensor.py).
SENSOR_VALUES = {
    "frame_rate_hz": 25.0,
    "frame_phase_s": 0.012,
    "latency_s": 0.1,
    "latency_jitter_s": 0.02,
    "jitter_s": 0.003,
    "frame_drop_prob": 0.3,
    "measurement_noise_px": 2.0,
    "image_noise_std": 8.0,
    "calib_focal_error": 0.05,
    "calib_principal_point_error_px": 5.0,
    "calib_rotation_error_deg": 2.0,
    "calib_translation_error_m": 0.02,
    "calib_error_draw": "fixed",
    "image_width_px": 160,
    "image_height_px": 120,
}


def test_every_sensor_option_is_covered():
    from observer_gym.envs.sensor import SensorConfig

    fields = {f.name for f in dataclasses.fields(SensorConfig)} - {"obs_mode"}
    assert fields == set(SENSOR_VALUES)


@pytest.mark.parametrize(
    ("key", "env_id"),
    [  # each option on one world in the default run, the worlds in turn (every world and
        # every option there); its other two worlds in the slow step (0.1-3.2 s each idle)
        (key, env_id)
        if sorted(WORLDS).index(env_id) == sorted(SENSOR_VALUES).index(key) % len(WORLDS)
        else pytest.param(key, env_id, marks=pytest.mark.slow)
        for env_id in sorted(WORLDS)
        for key in sorted(SENSOR_VALUES)
    ],
)
def test_a_sensor_option_does_not_change_the_worlds_draws(env_id, key):
    """Every sensor option draws from the sensor's own streams: the pushes, occluders,
    throws and target motion of a seed are the same at any value (but for a frame rate
    that is also the env's control rate, which the sweep warns of)."""
    options = WORLDS[env_id]
    value = SENSOR_VALUES[key]
    if key == "frame_phase_s" and env_id.endswith("TargetFollower-v0"):
        value = 0.05  # below its 0.1 s frame period, on a physics tick
    grid = check_grid(env_id, {key: [str(value)]}, options)
    # Image noise exists on rendered frames only.
    obs_mode = "rgb" if key == "image_noise_std" else "measurements"
    (first, second), (first_set, second_set) = (
        _world(env_id, 60, obs_mode=obs_mode, **options, **extra) for extra in ({}, {key: value})
    )
    shaping = system_for_id(env_id).env_class().world_shaping_sensor_options
    if key in shaping:
        assert first.shape != first_set.shape or not np.array_equal(first, first_set)
        (note,) = world_draw_notes(env_id, check_grid(env_id, {key: ["50", "25"]}, options))
        assert key in note and "control rate" in note
    else:
        # Over the steps both ran (a smaller image loses an unfollowed target sooner, which
        # ends TargetFollower's episode: the image decides that, not the world's draws).
        # The next, unseeded episode goes on from where the world's generator stood, so it
        # is the same when the first episodes ran equally long.
        pairs = [(first, first_set)] + [(second, second_set)] * (len(first) == len(first_set))
        for default, changed in pairs:
            steps = min(len(default), len(changed))
            assert steps >= 20
            assert np.array_equal(default[:steps], changed[:steps])
        assert not world_draw_notes(env_id, grid)


# --- resuming --------------------------------------------------------------------------------
class Interrupted(Exception):
    pass


# a killed sweep in a process (26 s at load 7); test_fuzz_sweep_cells.py keeps cell reuse
@pytest.mark.slow
def test_an_interrupted_sweep_resumes_without_rerunning_cells(swept, tmp_path, monkeypatch):
    reference, _ = swept
    calls = []
    real = sweep.sweep_episode

    def counted(spec, stop_after=None):
        if stop_after is not None and len(calls) == stop_after:
            raise Interrupted
        calls.append(spec)
        return real(spec)

    out_dir = tmp_path / "out"
    monkeypatch.setattr(sweep, "sweep_episode", lambda spec: counted(spec, 3 * EPISODES))
    with pytest.raises(Interrupted):
        run_sweep(**ARGS, out_dir=out_dir)
    assert len(list((out_dir / "cells").glob("*.json"))) == 3
    assert not (out_dir / "results.json").exists()

    calls.clear()
    monkeypatch.setattr(sweep, "sweep_episode", counted)
    result = run_sweep(**ARGS, out_dir=out_dir)
    assert (result.cells_run, result.cells_reused) == (5, 3)
    assert len(calls) == 5 * EPISODES
    ran = {(s.observer.name, s.controller.name, s.env_kwargs[KEY]) for s in calls}
    assert len(ran) == 5  # no finished cell ran again
    for name in OUTPUTS:
        assert (out_dir / name).read_bytes() == (reference / name).read_bytes(), name

    calls.clear()
    again = run_sweep(**ARGS, out_dir=out_dir)  # all finished: nothing runs
    assert calls == [] and (again.cells_run, again.cells_reused) == (0, 8)
    for name in OUTPUTS:
        assert (out_dir / name).read_bytes() == (reference / name).read_bytes(), name


@pytest.mark.slow
def test_a_killed_sweep_resumes_to_the_outputs_of_an_uninterrupted_one(swept, tmp_path):
    reference, _ = swept
    out_dir = tmp_path / "out"
    argv = [*CLI, *ARGV, "--out", str(out_dir)]
    process = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while not list((out_dir / "cells").glob("*.json")) and time.monotonic() < deadline:
        assert process.poll() is None, "the sweep ended before its first cell"
        time.sleep(0.01)
    os.kill(process.pid, signal.SIGKILL)
    process.wait()
    finished = len(list((out_dir / "cells").glob("*.json")))
    assert 1 <= finished < 8

    result = subprocess.run(argv, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert f"{8 - finished} cell(s) run, {finished} reused" in result.stdout
    assert "was killed before it finished" in result.stderr  # the marker it left
    for name in OUTPUTS:
        assert (out_dir / name).read_bytes() == (reference / name).read_bytes(), name


def test_off_a_terminal_each_finished_cell_is_one_line_on_stderr(tmp_path, capsys):
    argv = [a for a in ARGV if a != "--no-progress"]
    argv[argv.index("--episodes") + 1] = "1"
    argv[argv.index("--observers") + 1] = "oracle"
    argv[argv.index("--controllers") + 1] = "lqr"
    assert main([*argv, "--out", str(tmp_path / "lines")]) == 0  # stderr is no terminal here
    lines = capsys.readouterr().err.splitlines()
    assert [line.split(" (")[0] for line in lines] == [
        f"observer-gym sweep: cell {k}/2 finished: {KEY}={value}, oracle + lqr, 1 episode"
        for k, value in ((1, 0.0), (2, 2.0))
    ]
    assert main([*argv, "--out", str(tmp_path / "quiet"), "--no-progress"]) == 0
    assert capsys.readouterr().err == ""


def test_other_arguments_into_the_same_folder_are_refused(swept, capsys):
    out_dir, _ = swept
    before = {p: p.read_bytes() for p in out_dir.rglob("*") if p.is_file()}
    argv = [*ARGV, "--out", str(out_dir)]
    argv[argv.index(f"{KEY}=0,2")] = f"{KEY}=0,3"
    argv[argv.index("--episodes") + 1] = "4"
    assert main(argv) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith("observer-gym sweep: error: ") and "holds a sweep with other" in line
    assert f'vary {{"{KEY}":[0.0,2.0]}} there, {{"{KEY}":[0.0,3.0]}} here' in line
    assert "episodes 3 there, 4 here" in line
    assert {p: p.read_bytes() for p in out_dir.rglob("*") if p.is_file()} == before


# --- backends --------------------------------------------------------------------------------
@pytest.mark.slow  # a local Ray instance takes 10-20 s to start on two busy cores
def test_ray_gives_the_local_numbers(tmp_path):
    pytest.importorskip("ray")
    args = {**ARGS, "controllers": ["lqr"], "episodes": 2, "steps": 20}
    local = run_sweep(**args, out_dir=tmp_path / "local")
    remote = run_sweep(**args, out_dir=tmp_path / "ray", backend="ray")
    assert remote.results["cells"] == local.results["cells"]
    assert remote.results["episodes"] == local.results["episodes"]
    for name in ("episodes.csv", "table.md"):
        assert (tmp_path / "ray" / name).read_bytes() == (tmp_path / "local" / name).read_bytes()


@pytest.mark.slow  # two spawned workers import the layers: about 10 s of CPU
def test_two_workers_give_the_numbers_of_one(swept, tmp_path):
    reference, _ = swept
    run_sweep(**ARGS, out_dir=tmp_path / "out", workers=2)
    for name in OUTPUTS:
        assert (tmp_path / "out" / name).read_bytes() == (reference / name).read_bytes(), name


# --- mistakes --------------------------------------------------------------------------------
BASE = ["sweep", "--observers", "oracle", "--controllers", "lqr", "--no-progress"]
MISTAKES = {
    "unknown-key": (
        ["--vary", "latency=0,0.1"],
        "has no option 'latency' (did you mean 'latency_s'?); allowed: image_width_px,",
    ),
    "out-of-range": (
        ["--vary", "latency_s=0,0.9"],
        "latency_s=0.9 is out of range; allowed: [0.0, 0.5]",
    ),
    "wrong-type": (
        ["--vary", "latency_s=0,fast"],
        "latency_s='fast' is not a number; allowed: [0.0, 0.5]",
    ),
    "not-an-integer": (
        ["--vary", "physics_substeps=2.5"],
        "physics_substeps='2.5' is not an integer; allowed: [1, 50]",
    ),
    "not-a-choice": (["--vary", "camera_motion=fixed,spin"], "choose one of ['fixed', 'head']"),
    "between-options": (["--vary", "frame_phase_s=0,0.03"], "must be below one frame period"),
    "empty-list": (["--vary", "latency_s="], "argument --vary: latency_s has an empty value list"),
    "empty-value": (["--vary", "latency_s=0,,1"], "argument --vary: latency_s has an empty value"),
    "duplicate-key": (
        ["--vary", "latency_s=0", "--vary", "latency_s=0.1"],
        "vary names latency_s more than once",
    ),
    "duplicate-value": (["--vary", "latency_s=0,0.0"], "the value 0.0 appears more than once"),
    "also-fixed": (
        ["--vary", "latency_s=0", "--env-option", "latency_s=0.1"],
        "latency_s is also set as an env option",
    ),
    "obs-mode": (["--vary", "obs_mode=rgb"], "obs_mode cannot vary"),
    "unknown-observer": (
        ["--vary", "latency_s=0", "--observers", "oracle,ekf-magic"],
        "unknown observer 'ekf-magic'",
    ),
    "unknown-controller": (
        ["--vary", "latency_s=0", "--controllers", "lqg"],
        "unknown controller 'lqg'; allowed: lqr, mpc, pid",
    ),
    "no-episodes": (
        ["--vary", "latency_s=0", "--episodes", "0"],
        "argument --episodes: must be an integer >= 1",
    ),
    "negative-seed": (
        ["--vary", "latency_s=0", "--seed", "-1"],
        "argument --seed: must be an integer >= 0",
    ),
    "unknown-metric": (
        ["--vary", "latency_s=0", "--second-metric", "speed"],
        "unknown metric 'speed'",
    ),
}


@pytest.mark.parametrize("case", sorted(MISTAKES))
def test_a_mistake_is_one_line_exit_code_2_and_writes_nothing(case, tmp_path, capsys):
    extra, message = MISTAKES[case]
    out_dir = tmp_path / "out"
    argv = [*BASE, *extra, "--out", str(out_dir)]
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own checks
        code = exc.code
    captured = capsys.readouterr()
    assert code == 2
    (line,) = captured.err.splitlines()
    assert line.startswith("observer-gym sweep: error: ") and message in line, line
    assert captured.out == ""
    assert not out_dir.exists()


def test_a_mistake_is_found_before_the_heavy_imports(tmp_path):
    probe = (
        "import sys\nfrom observer_gym.train.cli import main\ncode = main(sys.argv[1:])\n"
        # the multi-second imports (the layers are read for the systems' names)
        "heavy = ('torch', 'ray', 'stable_baselines3', 'observer_gym.train.experiments.sweep.')\n"
        "loaded = sorted(m for m in sys.modules if m.startswith(heavy))\n"
        "print(code, loaded, 'observer_gym.train.experiments.sweep' in sys.modules)\n"
    )
    argv = [*BASE, "--vary", "latency=0", "--out", str(tmp_path / "out")]
    result = subprocess.run(
        [sys.executable, "-c", probe, *argv], capture_output=True, text=True, timeout=120
    )
    assert result.stdout.strip() == "2 [] False", result.stdout + result.stderr
    assert "observer-gym sweep: error: vary: BallTable-v0 has no option 'latency'" in result.stderr


def test_the_library_refuses_bad_counts_and_warns_of_world_draws(tmp_path):
    for changes, message in (
        ({"episodes": 0}, "episodes must be an integer >= 1, got 0"),
        ({"seed": -1}, "seed must be an integer >= 0, got -1"),
        ({"vary": {}}, "vary must name at least one env option"),
        ({"vary": {KEY: []}}, f"vary {KEY}: no values given"),
    ):
        with pytest.raises(ValueError, match=message):
            run_sweep(**{**ARGS, **changes}, out_dir=tmp_path / "out")
        assert not (tmp_path / "out").exists()
    args = {**ARGS, "vary": {"frame_rate_hz": [50, 25]}, "observers": ["oracle"], "episodes": 1}
    with pytest.warns(SweepWarning, match="varying frame_rate_hz changes the world's steps"):
        run_sweep(**{**args, "controllers": ["lqr"], "steps": 5}, out_dir=tmp_path / "out")
    assert (tmp_path / "out" / "results.json").exists()
