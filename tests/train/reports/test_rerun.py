"""``--rerun FILE.rrd``: an episode's recording for the rerun viewer
(train/reports/rerun_recording.py), read back with rerun-sdk's own reader
(``rerun.chunk.RrdReader``).

What a written recording must hold: one image per delivered frame, the truth where
``info["state"]`` puts the ball, the estimate's ellipsoid with the covariance's axes, each
camera's nominal and true pose as the frames gave them, the NEES the run reports; what it
must not do: change the episode's numbers, or leave a file or a temp after a failure.
"""

from __future__ import annotations

import collections
import dataclasses
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

pytest.importorskip("rerun")

import pyarrow as pa
from rerun.chunk import RrdReader
from scipy.spatial.transform import Rotation

from observer_gym.envs import system_for_id
from observer_gym.train.cli import main
from observer_gym.train.core.atomic_write import WriteError
from observer_gym.train.core.observer_env import make_env, resolve_observer
from observer_gym.train.experiments.episode import EpisodeSpec, build_controller, run_episode
from observer_gym.train.experiments.request import resolve_controller
from observer_gym.train.reports import rerun_recording
from observer_gym.train.reports.rerun_recording import EpisodeRerun, RerunRequest

TABLE = "observer_gym/BallTable-v0"
CATCHER = "observer_gym/BallCatcher-v1"
# BallCatcher with a fixed 2-degree rotation error: nominal and true cameras differ
MISCALIBRATED = {"calib_rotation_error_deg": 2.0, "calib_error_draw": "fixed"}


class Logged:
    """A .rrd file's rows by entity: (time in s, {component: value}) in time order."""

    def __init__(self, path: Path) -> None:
        rows = collections.defaultdict(list)
        for chunk in RrdReader(path).stream().to_chunks():
            batch = chunk.to_record_batch()
            names = batch.schema.names
            times = (
                batch.column("sim_time_s").cast(pa.int64()).to_pylist()
                if "sim_time_s" in names
                else [None] * batch.num_rows
            )
            columns = {n: batch.column(n).to_pylist() for n in names if ":" in n}
            for i, t in enumerate(times):
                row = {n: values[i] for n, values in columns.items() if values[i] is not None}
                rows[chunk.entity_path].append((None if t is None else t * 1e-9, row))
        self.rows = {
            entity: sorted(found, key=lambda r: -1.0 if r[0] is None else r[0])
            for entity, found in rows.items()
        }

    def at(self, entity: str, time_s: float, component: str):
        """The value of ``component`` logged on ``entity`` at ``time_s``."""
        found = [
            row[component]
            for t, row in self.rows[entity]
            if t is not None and abs(t - time_s) < 1e-9 and component in row
        ]
        assert len(found) == 1, (entity, time_s, component, len(found))
        return found[0]

    def count(self, entity: str, component: str) -> int:
        return sum(component in row for _, row in self.rows.get(entity, []))


def record(path: Path, env_id: str, controller: str, steps: int, env_options=None, seed=3):
    """A kf episode of ``steps`` steps recorded into ``path``; each step's info (the
    reset's first) with the frames it delivered per camera."""
    system = system_for_id(env_id)
    env = make_env(system, resolve_observer(system, "kf"), env_options)
    try:
        built = build_controller(resolve_controller(system, controller), env, system)
        built.reset()
        observe = getattr(built, "observe_info", lambda info: None)
        with EpisodeRerun(RerunRequest(str(path), "test"), env) as recording:
            obs, info = env.reset(seed=seed)
            observe(info)
            recording.add(info, 0)
            infos = [info]
            for step in range(1, steps + 1):
                action, _ = built.predict(obs)
                obs, _, terminated, truncated, info = env.step(action)
                observe(info)
                recording.add(info, step, action)
                infos.append(info)
                if terminated or truncated:
                    break
        return infos
    finally:
        env.close()


def delivered(infos, camera: int) -> int:
    return sum(int(f["camera_id"]) == camera for info in infos for f in info["frames"])


def test_ball_table_one_image_per_delivered_frame_and_the_truth_on_the_true_table(tmp_path):
    path = tmp_path / "table.rrd"
    infos = record(path, TABLE, "lqr", 12)
    logged = Logged(path)
    assert path.is_file() and not list(tmp_path.glob(".*tmp*"))
    images = logged.count("/world/camera0/true/image", "EncodedImage:blob")
    assert images == delivered(infos, 0) > 10
    # the truth at step 10: the state's table-frame (x, y) at the ball's radius above the
    # top, on the table's true pose
    info = infos[10]
    T = np.asarray(info["T_world_table"])
    centre = T[:3, :3] @ np.array([info["state"][0], info["state"][1], 0.025]) + T[:3, 3]
    truth = logged.at("/world/ball/truth", info["time_s"], "Points3D:positions")
    np.testing.assert_allclose(truth[0], centre, atol=1e-6)
    # the arm: from its base (the world's origin) to the flange, which holds the table's
    # top 55 mm above it along the table's normal (envs/ball_table/geometry.py)
    assert logged.count("/world/robot", "LineStrips3D:strips") == len(infos)
    joints = np.asarray(logged.at("/world/robot", info["time_s"], "LineStrips3D:strips")[0])
    np.testing.assert_allclose(joints[0], [0.0, 0.0, 0.0], atol=1e-6)
    flange_in_table = T[:3, :3].T @ (joints[-1] - T[:3, 3])
    np.testing.assert_allclose(flange_in_table, [0.0, 0.0, -0.055], atol=1e-5)
    # the table drawn as the five boxes of its URDF (top and four borders)
    boxes = logged.rows["/world/table/boxes"][0][1]
    assert len(boxes["Boxes3D:half_sizes"]) == 5
    np.testing.assert_allclose(
        sorted(map(tuple, boxes["Boxes3D:half_sizes"]))[-1], (0.15, 0.15, 0.005), atol=1e-6
    )


def test_ball_catcher_truth_ellipsoid_and_cameras_are_what_the_episode_gave(tmp_path):
    path = tmp_path / "catcher.rrd"
    infos = record(path, CATCHER, "intercept", 30, MISCALIBRATED)
    logged = Logged(path)
    for camera in (0, 1):
        images = logged.count(f"/world/camera{camera}/true/image", "EncodedImage:blob")
        assert images == delivered(infos, camera) > 3
    step = next(k for k in range(len(infos) - 1, 0, -1) if infos[k]["frames"])
    info = infos[step]
    t = info["time_s"]
    truth = logged.at("/world/ball/truth", t, "Points3D:positions")
    np.testing.assert_allclose(truth[0], info["state"][:3], atol=1e-5)
    # the ellipsoid: 2-sigma half sizes along axes whose rotation gives back P's block
    P = np.asarray(info["estimate"]["covariance"])[:3, :3]
    entity = "/world/ball/estimate/ellipsoid"
    half = np.asarray(logged.at(entity, t, "Ellipsoids3D:half_sizes")[0], dtype=float)
    quaternion = np.asarray(logged.at(entity, t, "Ellipsoids3D:quaternions")[0], dtype=float)
    R = Rotation.from_quat(quaternion).as_matrix()
    np.testing.assert_allclose(R @ np.diag((half / 2) ** 2) @ R.T, P, rtol=1e-4, atol=1e-12)
    centre = logged.at(entity, t, "Ellipsoids3D:centers")[0]
    np.testing.assert_allclose(centre, info["estimate"]["mean"][:3], atol=1e-5)
    # each delivered camera's nominal and true pose, as the frame and the truth gave them
    nominal, true = info["frames"][-1], info["truth"]["frames"][-1]
    camera = int(nominal["camera_id"])
    for kind, frame in (("nominal", nominal), ("true", true)):
        entity = f"/world/camera{camera}/{kind}"
        T = np.asarray(frame["T_world_cam"])
        np.testing.assert_allclose(
            logged.at(entity, t, "Transform3D:translation")[0], T[:3, 3], atol=1e-5
        )
        # rerun keeps a 3x3 column by column
        mat = np.asarray(logged.at(entity, t, "Transform3D:mat3x3")[0]).reshape(3, 3).T
        np.testing.assert_allclose(mat, T[:3, :3], atol=1e-6)
        K = np.asarray(logged.at(entity, t, "Pinhole:image_from_camera")[0]).reshape(3, 3).T
        np.testing.assert_allclose(K, np.diag([2, 2, 1]) @ np.asarray(frame["K"]), rtol=1e-6)
    assert not np.allclose(nominal["T_world_cam"], true["T_world_cam"], atol=1e-4)
    assert len(RrdReader(path).blueprints()) == 1  # the viewer's default layout


def test_the_image_matches_its_pinhole(tmp_path):
    """The viewer lays an image into its camera's frustum by the pinhole's resolution: the
    logged (enlarged) image has exactly that size."""
    path = tmp_path / "table.rrd"
    record(path, TABLE, "lqr", 3)
    logged = Logged(path)
    t, row = logged.rows["/world/camera0/true/image"][-1]
    image = cv2.imdecode(np.asarray(row["EncodedImage:blob"][0], np.uint8), 1)
    width, height = logged.at("/world/camera0/true", t, "Pinhole:resolution")[0]
    assert image.shape[:2] == (height, width) == (480, 640)


def test_the_episode_is_the_same_with_and_without_a_recording_and_nees_is_the_runs(tmp_path):
    spec = EpisodeSpec.of(CATCHER, "kf", "intercept", seed=5, max_steps=25)
    plain = run_episode(spec)
    path = tmp_path / "x.rrd"
    recorded = run_episode(dataclasses.replace(spec, rerun=RerunRequest(str(path), "x")))
    for key in ("time_s", "state", "estimate", "actions", "rewards", "nees"):
        np.testing.assert_array_equal(plain[key], recorded[key], err_msg=key)
    logged = Logged(path)
    rows = logged.rows["/metrics/nees"]
    assert rows
    by_time = {round(t, 9): row["Scalars:scalars"][0] for t, row in rows}
    finite = np.isfinite(plain["nees"])
    assert len(by_time) == finite.sum()  # none where the model does not hold
    for t, nees in zip(plain["time_s"][finite], plain["nees"][finite], strict=True):
        assert by_time[round(float(t), 9)] == pytest.approx(nees, rel=1e-12)


@pytest.mark.slow  # two runs of the command
def test_run_with_and_without_rerun_gives_the_same_episodes(tmp_path, capsys):
    argv = ["run", "--observer", "kf", "--controller", "lqr", "--episodes", "2", "--steps", "8"]
    argv += ["--no-progress"]
    assert main([*argv, "--out", str(tmp_path / "plain")]) == 0
    rrd = tmp_path / "rec" / "episode.rrd"
    rerun = ["--rerun", str(rrd), "--rerun-episode", "1"]
    assert main([*argv, "--out", str(tmp_path / "recorded"), *rerun]) == 0
    plain = json.loads((tmp_path / "plain" / "results.json").read_text())
    recorded = json.loads((tmp_path / "recorded" / "results.json").read_text())
    assert plain["episodes"] == recorded["episodes"]
    assert [p.name for p in rrd.parent.iterdir()] == ["episode.rrd"]
    assert len(RrdReader(rrd).recordings()) == 1
    properties = Logged(rrd).rows["/__properties"]
    names = [row["RecordingInfo:name"] for _, row in properties if "RecordingInfo:name" in row]
    assert names == [["BallTable-v0_kf_lqr_episode1_seed1"]]
    capsys.readouterr()


@pytest.mark.slow  # spawns worker processes
def test_a_worker_process_writes_the_recording(tmp_path, capsys):
    argv = ["run", "--observer", "kf", "--controller", "lqr", "--episodes", "2", "--steps", "8"]
    rrd = tmp_path / "episode.rrd"
    argv += ["--no-progress", "--workers", "2", "--rerun", str(rrd), "--rerun-episode", "1"]
    assert main([*argv, "--out", str(tmp_path / "r")]) == 0
    capsys.readouterr()
    assert [p.name for p in tmp_path.iterdir() if p.name != "r"] == ["episode.rrd"]
    assert Logged(rrd).count("/world/ball/truth", "Points3D:positions") == 9


def one_line_error(capsys, argv: list[str]) -> tuple[int, str]:
    code = main(argv)
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    return code, err


def test_bad_rerun_options_are_refused_in_one_line(tmp_path, capsys):
    argv = ["run", "--observer", "kf", "--controller", "lqr", "--episodes", "2"]
    argv += ["--out", str(tmp_path / "r")]
    code, err = one_line_error(capsys, [*argv, "--rerun", str(tmp_path / "x.mp4")])
    assert code == 2 and "--rerun takes a file ending in .rrd" in err
    code, err = one_line_error(capsys, [*argv, "--rerun-episode", "0"])
    assert code == 2 and "--rerun-episode needs --rerun FILE.rrd" in err
    code, err = one_line_error(
        capsys, [*argv, "--rerun", str(tmp_path / "x.rrd"), "--rerun-episode", "2"]
    )
    assert code == 2 and "outside the run's episodes 0..1" in err
    assert not (tmp_path / "r").exists() and not (tmp_path / "x.rrd").exists()


def test_a_failure_mid_episode_leaves_no_file(tmp_path, monkeypatch):
    real = EpisodeRerun.add

    def interrupted(self, info, step, action=None):
        if step == 5:
            raise KeyboardInterrupt
        real(self, info, step, action)

    monkeypatch.setattr(rerun_recording.EpisodeRerun, "add", interrupted)
    spec = EpisodeSpec.of(
        TABLE, "kf", "lqr", seed=0, max_steps=20, rerun=RerunRequest(str(tmp_path / "x.rrd"), "x")
    )
    with pytest.raises(KeyboardInterrupt):
        run_episode(spec)
    assert list(tmp_path.iterdir()) == []  # neither the file nor its temp


def test_rerun_turned_off_in_the_environment_is_refused_before_any_episode(
    tmp_path, capsys, monkeypatch
):
    """rerun-sdk writes nothing with RERUN=off (its own values: 0, false, off)."""
    monkeypatch.setenv("RERUN", "off")
    argv = ["run", "--observer", "kf", "--controller", "lqr", "--episodes", "1"]
    argv += ["--out", str(tmp_path / "r"), "--rerun", str(tmp_path / "x.rrd")]
    code, err = one_line_error(capsys, argv)
    assert code == 2 and "RERUN=off" in err
    assert list(tmp_path.iterdir()) == []


def test_a_folder_that_cannot_be_written_is_refused_before_any_episode(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("")
    argv = ["run", "--observer", "kf", "--controller", "lqr", "--episodes", "1"]
    argv += ["--out", str(tmp_path / "r"), "--rerun", str(blocker / "x.rrd")]
    code, err = one_line_error(capsys, argv)
    assert code == 1 and f"cannot write {blocker / 'x.rrd'}" in err
    assert not (tmp_path / "r").exists()


@pytest.mark.slow  # loads PyTorch and stable-baselines3
def test_evaluate_records_one_agents_episode_and_refuses_a_multi_seed_run(tmp_path, capsys):
    pytest.importorskip("stable_baselines3")
    import shutil

    from observer_gym.train.rl.run_dir import agent_folder

    rrd = tmp_path / "agent.rrd"
    argv = ["evaluate", "--episodes", "1", "--steps", "10", "--no-progress"]
    model = ["--model", "ppo:ball_table-estimate"]
    assert main([*argv, *model, "--out", str(tmp_path / "e"), "--rerun", str(rrd)]) == 0
    capsys.readouterr()
    assert Logged(rrd).count("/world/ball/truth", "Points3D:positions") == 11  # reset + 10
    multi = tmp_path / "multi"
    for seed in (0, 1):
        shutil.copytree(agent_folder("ppo:ball_table-estimate"), multi / f"seed_{seed}")
    rerun = ["--rerun", str(tmp_path / "multi.rrd")]
    code, err = one_line_error(
        capsys, [*argv, "--model", str(multi), "--out", str(tmp_path / "m"), *rerun]
    )
    assert code == 2 and "give one seed's run (--model DIR/seed_<s>)" in err
    assert not (tmp_path / "m").exists() and not (tmp_path / "multi.rrd").exists()


def test_a_recording_that_did_not_reach_the_disk_whole_is_one_write_error(tmp_path, monkeypatch):
    """rerun's writer logs a failed write (a full disk) instead of raising: the file is
    checked before the rename, and a cut one is dropped with its temp."""
    real = rerun_recording.EpisodeRerun.__init__

    def cut_on_close(self, request, env):
        real(self, request, env)
        disconnect = self.stream.disconnect

        def disconnect_and_cut():
            disconnect()
            data = self.tmp.read_bytes()
            self.tmp.write_bytes(data[: len(data) // 2])

        monkeypatch.setattr(self.stream, "disconnect", disconnect_and_cut)

    monkeypatch.setattr(rerun_recording.EpisodeRerun, "__init__", cut_on_close)
    spec = EpisodeSpec.of(
        TABLE, "kf", "lqr", seed=0, max_steps=10, rerun=RerunRequest(str(tmp_path / "x.rrd"), "x")
    )
    with pytest.raises(WriteError, match=r"could not write .*x\.rrd: the recording is incomplete"):
        run_episode(spec)
    assert list(tmp_path.iterdir()) == []
