"""Loading an agent folder runs none of its files' code: VecNormalize statistics are read
as plain arrays, a pickled ``vecnormalize.pkl`` of an earlier version is refused in one
line (and converted only by ``--trust-pickle``), and a folder whose files differ from the
sha256 its run recorded is refused in one line, for evaluate, run, compare and
train --resume."""

from __future__ import annotations

import json
import pickle
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest

from observer_gym.envs import system_for_id
from observer_gym.train.cli import main
from observer_gym.train.core.observer_env import make_env, resolve_observer
from observer_gym.train.rl import normalizer_file
from observer_gym.train.rl.agent import Agent
from observer_gym.train.rl.run_dir import file_sha256
from observer_gym.train.rl.ship_agent import fingerprint_difference
from observer_gym.train.rl.shipped import shipped_path

SHIPPED = "ball_table-estimate"
STEPS = 4096  # the checkpoint's timestep count in the folders made here


class _Payload:
    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):  # what unpickling would call: write the marker file
        return (open, (str(self.marker), "w"))


def _copy_shipped(folder: Path, *names: str) -> Path:
    folder.mkdir(parents=True)
    for name in names:
        shutil.copyfile(shipped_path(SHIPPED) / name, folder / name)
    return folder


def _old_finished_run(tmp_path: Path, marker: Path) -> Path:
    """A finished run as an earlier version wrote it, its vecnormalize.pkl crafted."""
    folder = _copy_shipped(tmp_path / "old", "config.json", "model.zip", "state.json")
    (folder / "vecnormalize.pkl").write_bytes(pickle.dumps(_Payload(marker)))
    return folder


def _old_checkpointed_run(tmp_path: Path, marker: Path) -> Path:
    """An interrupted run as an earlier version wrote it: a checkpoint whose
    vecnormalize_<N>.pkl is crafted, its sha256 recorded (so the set is intact)."""
    folder = _copy_shipped(tmp_path / "old-ckpt", "config.json")
    checkpoints = folder / "checkpoints"
    checkpoints.mkdir()
    shutil.copyfile(shipped_path(SHIPPED) / "model.zip", checkpoints / f"model_{STEPS}.zip")
    (checkpoints / f"vecnormalize_{STEPS}.pkl").write_bytes(pickle.dumps(_Payload(marker)))
    _write_manifest(checkpoints, f"vecnormalize_{STEPS}.pkl")
    (folder / "state.json").write_text(json.dumps({"status": "interrupted", "timesteps": STEPS}))
    return folder


def _write_manifest(checkpoints: Path, stats: str) -> None:
    entry = {"timesteps": STEPS, "model": f"model_{STEPS}.zip", "vecnormalize": stats}
    entry["sha256"] = {name: file_sha256(checkpoints / name) for name in (entry["model"], stats)}
    for name in (f"checkpoint_{STEPS}.json", "latest.json"):
        (checkpoints / name).write_text(json.dumps(entry))


def _commands(folder: Path, out: Path) -> dict[str, list[str]]:
    common = ["--no-progress", "--out", str(out)]
    episode = ["--episodes", "1", "--steps", "2", *common]
    return {
        "evaluate": ["evaluate", "--model", str(folder), *episode],
        "run": ["run", "--controller", f"ppo:{folder}", "--observer", "kf-measurements", *episode],
        "compare": [
            "compare",
            "--observers",
            "kf-measurements",
            "--controllers",
            f"lqr,ppo:{folder}",
            *episode,
        ],
    }


def _one_line(capsys) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    return err


@pytest.mark.parametrize("command", ["evaluate", "run", "compare"])
def test_a_crafted_vecnormalize_pickle_is_refused_and_runs_nothing(tmp_path, capsys, command):
    marker = tmp_path / "ran"
    folder = _old_finished_run(tmp_path, marker)
    code = main(_commands(folder, tmp_path / "out")[command])
    assert not marker.exists()  # unpickling would have written it
    assert code == 2
    err = _one_line(capsys)
    assert "vecnormalize.pkl holds VecNormalize statistics as a pickle" in err
    assert f"{normalizer_file.CONVERT_COMMAND} {folder}" in err


@pytest.mark.parametrize("command", ["evaluate", "run"])
def test_a_crafted_checkpoint_pickle_is_refused_and_runs_nothing(tmp_path, capsys, command):
    marker = tmp_path / "ran"
    folder = _old_checkpointed_run(tmp_path, marker)
    code = main(_commands(folder, tmp_path / "out")[command])
    assert not marker.exists()  # unpickling would have written it
    assert code == 2
    assert f"vecnormalize_{STEPS}.pkl holds VecNormalize statistics" in _one_line(capsys)


def test_resume_refuses_a_crafted_checkpoint_pickle_and_runs_nothing(tmp_path, capsys):
    marker = tmp_path / "ran"
    folder = _old_checkpointed_run(tmp_path, marker)
    argv = ["train", "--no-progress", "--resume", str(folder), "--timesteps", str(STEPS)]
    code = main(argv)
    assert not marker.exists()  # unpickling would have written it
    assert code == 2
    err = _one_line(capsys)
    assert f"vecnormalize_{STEPS}.pkl holds VecNormalize statistics as a pickle" in err
    assert f"{normalizer_file.CONVERT_COMMAND} {folder}" in err


def _rezipped(path: Path) -> None:
    """Rewrite the zip ``path`` with one more (harmless) member: still a zip SB3 loads,
    no longer the file the run saved."""
    with zipfile.ZipFile(path) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    with zipfile.ZipFile(path, "w") as archive:
        for name, data in {**members, "note.txt": b"changed"}.items():
            archive.writestr(name, data)


def _tampered_stats(path: Path) -> None:
    stats = normalizer_file.read_stats(path)
    normalizer_file.write_stats(
        normalizer_file.NormalizerStats(**{**vars(stats), "clip_obs": 3.0}), path
    )


@pytest.mark.parametrize(
    ("name", "tamper"), [("model.zip", _rezipped), ("vecnormalize.npz", _tampered_stats)]
)
def test_a_finished_agent_whose_files_changed_is_refused(tmp_path, capsys, name, tamper):
    folder = tmp_path / "agent"
    shutil.copytree(shipped_path(SHIPPED), folder)
    tamper(folder / name)
    assert main(_commands(folder, tmp_path / "out")["evaluate"]) == 2
    err = _one_line(capsys)
    assert f"{folder / name} is not the file the run saved" in err
    assert "final.json" in err
    with pytest.raises(ValueError, match="is not the file the run saved"):
        Agent.load(folder)


def test_a_checkpointed_agent_whose_model_changed_is_refused(tmp_path, capsys):
    folder = _copy_shipped(tmp_path / "ckpt", "config.json")
    checkpoints = folder / "checkpoints"
    checkpoints.mkdir()
    shutil.copyfile(shipped_path(SHIPPED) / "model.zip", checkpoints / f"model_{STEPS}.zip")
    shutil.copyfile(
        shipped_path(SHIPPED) / "vecnormalize.npz", checkpoints / f"vecnormalize_{STEPS}.npz"
    )
    _write_manifest(checkpoints, f"vecnormalize_{STEPS}.npz")
    assert Agent.load(folder).timesteps == STEPS  # as recorded: loads
    _rezipped(checkpoints / f"model_{STEPS}.zip")
    assert main(_commands(folder, tmp_path / "out")["run"]) == 2
    assert f"model_{STEPS}.zip is damaged (not the file that was saved)" in _one_line(capsys)


def test_a_crafted_npz_is_refused_and_runs_nothing(tmp_path):
    marker = tmp_path / "ran"
    crafted = tmp_path / "vecnormalize.npz"
    with open(crafted, "wb") as f:  # an object array is stored as a pickle
        np.savez(f, format=np.array(normalizer_file.STATS_FORMAT), obs=np.array([_Payload(marker)]))
    with pytest.raises(ValueError, match="is not a statistics file of plain arrays"):
        normalizer_file.read_stats(crafted)
    assert not marker.exists()


@pytest.mark.parametrize(
    "content",
    [b"", b"not a zip", pickle.dumps({"format": 1}), b"\x93NUMPY"],
    ids=["empty", "text", "pickle", "npy header"],
)
def test_a_file_that_is_no_statistics_is_one_value_error(tmp_path, content):
    path = tmp_path / "vecnormalize.npz"
    path.write_bytes(content)
    with pytest.raises(ValueError, match="is not a statistics file"):
        normalizer_file.read_stats(path)
    np.save(path.with_suffix(".npy"), np.zeros(3))
    path.write_bytes(path.with_suffix(".npy").read_bytes())  # one array, no archive
    with pytest.raises(ValueError, match=r"one array, not an \.npz archive"):
        normalizer_file.read_stats(path)


def test_the_statistics_round_trip_into_a_vec_normalize(tmp_path):
    """Saved and rebuilt, the statistics normalise as the VecNormalize they came from,
    for a Box and a Dict observation."""
    import gymnasium as gym
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    class _DictEnv(gym.Env):
        observation_space = gym.spaces.Dict(
            {"a": gym.spaces.Box(-1, 1, (3,)), "b": gym.spaces.Box(-1, 1, (2, 2))}
        )
        action_space = gym.spaces.Box(-1, 1, (1,))

    rng = np.random.default_rng(0)
    for make in (lambda: gym.make("Pendulum-v1"), _DictEnv):
        original = VecNormalize(DummyVecEnv([make]), clip_obs=4.0, gamma=0.9)
        samples = [original.observation_space.sample() for _ in range(50)]
        for sample in samples:  # move the running statistics off their defaults
            if isinstance(sample, dict):
                for key, value in sample.items():
                    original.obs_rms[key].update(value[None] * 3 + 1)
            else:
                original.obs_rms.update(sample[None] * 3 + 1)
        original.ret_rms.update(rng.normal(size=7))
        path = tmp_path / "stats.npz"
        normalizer_file.save_normalizer(original, path)
        rebuilt = normalizer_file.build_vec_normalize(
            normalizer_file.read_stats(path), DummyVecEnv([make]), training=False
        )
        assert (rebuilt.clip_obs, rebuilt.gamma, rebuilt.training) == (4.0, 0.9, False)
        for sample in samples:
            expected, got = original.normalize_obs(sample), rebuilt.normalize_obs(sample)
            if isinstance(sample, dict):
                for key in sample:
                    np.testing.assert_array_equal(got[key], expected[key])
            else:
                np.testing.assert_array_equal(got, expected)
        np.testing.assert_array_equal(
            rebuilt.normalize_reward(np.array([2.5])), original.normalize_reward(np.array([2.5]))
        )


def test_converting_an_old_folder_needs_trust_and_keeps_what_the_agent_does(tmp_path, capsys):
    """An old folder (a pickled vecnormalize.pkl) converts only with --trust-pickle, and
    then acts as the pickled statistics made it act."""
    from stable_baselines3.common.vec_env import VecNormalize

    folder = tmp_path / "old"
    shutil.copytree(shipped_path(SHIPPED), folder)
    agent = Agent.load(folder)
    agent.obs_normalizer.save(folder / "vecnormalize.pkl")  # as the earlier version did
    for name in ("vecnormalize.npz", "final.json"):
        (folder / name).unlink()
    with pytest.raises(ValueError, match="holds VecNormalize statistics as a pickle"):
        Agent.load(folder)

    assert normalizer_file.main([str(folder)]) == 2
    assert "give --trust-pickle" in _one_line(capsys)
    assert (folder / "vecnormalize.pkl").is_file()

    assert normalizer_file.main(["--trust-pickle", str(folder)]) == 0
    assert not (folder / "vecnormalize.pkl").exists()
    assert (folder / "vecnormalize.npz").is_file() and (folder / "final.json").is_file()
    # the statistics convert exactly (above); torch's arithmetic on a loaded machine may
    # differ in the last bits (4.7e-9 seen), the tolerance every shipped agent is held to
    assert fingerprint_difference(folder) <= 1e-6
    pickled = VecNormalize.__new__(VecNormalize)
    pickled.__setstate__(agent.obs_normalizer.__getstate__())
    system = system_for_id("observer_gym/BallTable-v0")
    env = make_env(system, resolve_observer(system, "kf-measurements"))
    try:
        obs, _ = env.reset(seed=1)
    finally:
        env.close()
    np.testing.assert_array_equal(
        Agent.load(folder).obs_normalizer.normalize_obs(obs), pickled.normalize_obs(obs)
    )


def test_converting_a_checkpointed_folder_rewrites_its_records(tmp_path):
    folder = _copy_shipped(tmp_path / "old-ckpt", "config.json")
    checkpoints = folder / "checkpoints"
    checkpoints.mkdir()
    shutil.copyfile(shipped_path(SHIPPED) / "model.zip", checkpoints / f"model_{STEPS}.zip")
    Agent.load(shipped_path(SHIPPED)).obs_normalizer.save(checkpoints / f"vecnormalize_{STEPS}.pkl")
    _write_manifest(checkpoints, f"vecnormalize_{STEPS}.pkl")
    written = normalizer_file.convert_folder(folder)
    assert written == [checkpoints / f"vecnormalize_{STEPS}.npz"]
    assert not list(checkpoints.glob("*.pkl"))
    latest = json.loads((checkpoints / "latest.json").read_text())
    assert latest["vecnormalize"] == f"vecnormalize_{STEPS}.npz"
    assert set(latest["sha256"]) == {f"model_{STEPS}.zip", f"vecnormalize_{STEPS}.npz"}
    assert Agent.load(folder).timesteps == STEPS


@pytest.mark.parametrize(
    ("content", "says"),
    [
        (b"garbage", "UnpicklingError"),  # cut or damaged
        (pickle.dumps({"a": 1}), "AttributeError"),  # a pickle of something else
    ],
)
def test_the_converter_refuses_a_pickle_that_holds_no_statistics_in_one_line(
    tmp_path, capsys, content, says
):
    (tmp_path / "config.json").write_text("{}")
    (tmp_path / "vecnormalize.pkl").write_bytes(content)
    assert normalizer_file.main(["--trust-pickle", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert "holds no VecNormalize statistics" in err and says in err
    assert (tmp_path / "vecnormalize.pkl").read_bytes() == content  # nothing removed


def test_statistics_of_another_observation_kind_are_a_value_error(tmp_path):
    """Statistics of other Dict keys, or of one array for a Dict (and the reverse), are
    refused with ValueError (which the commands report in one line), not SB3's KeyError."""
    import gymnasium as gym
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    def dict_env(keys):
        class _DictEnv(gym.Env):
            observation_space = gym.spaces.Dict({k: gym.spaces.Box(-1, 1, (2,)) for k in keys})
            action_space = gym.spaces.Box(-1, 1, (1,))

        return _DictEnv

    box = lambda: gym.make("Pendulum-v1")  # noqa: E731
    for saved_from, loaded_into, says in (
        (dict_env("a"), dict_env("b"), r"observation keys \['a'\] the env does not have"),
        (box, dict_env("b"), "of one observation array"),
        (dict_env("a"), box, "per observation key"),
    ):
        path = tmp_path / "stats.npz"
        normalizer_file.save_normalizer(VecNormalize(DummyVecEnv([saved_from])), path)
        with pytest.raises(ValueError, match=says):
            normalizer_file.build_vec_normalize(
                normalizer_file.read_stats(path), DummyVecEnv([loaded_into]), training=False
            )
