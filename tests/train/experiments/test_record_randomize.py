"""``observer-gym record --randomize``: each episode draws its env options and then its
world's seed from one generator seeded with ``--seed`` (the learned observers'
collections' scheme), keeps both in its metadata, and replays from them; bad ranges are
refused before anything is written."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest

pytest.importorskip("minari")
pytest.importorskip("h5py")

import minari

from observer_gym.train.cli import main
from observer_gym.train.experiments.record import WORLD_SEEDS_BELOW, record_experiment
from observer_gym.train.reports.dataset import read_recording, recording_record
from observer_gym.train.rl.randomize import union_space

ENV, OBSERVER, CONTROLLER = "BallTable-v0", "kf-measurements", "lqr"
SEED, EPISODES, STEPS = 11, 3, 10
FIXED = {"measurement_noise_px": 0.5}
RANDOMIZE = {
    "latency_s": {"low": 0.0, "high": 0.05},
    "frame_drop_prob": {"low": 0.0, "high": 0.2},
    "calib_error_draw": {"choices": ["per_episode", "fixed"]},
}


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    out = tmp_path_factory.mktemp("randomized") / "dataset"
    record = record_experiment(
        ENV, OBSERVER, CONTROLLER, EPISODES, SEED, out, steps=STEPS, progress=False,
        env_kwargs=FIXED, randomize=RANDOMIZE,
    )  # fmt: skip
    return out, record


def replayed(env_kwargs: dict, seed: int, actions: np.ndarray) -> tuple[dict, np.ndarray]:
    """The measurements and true states of the env made with ``env_kwargs``, reset with
    ``seed`` and stepped with ``actions``, each stacked over the steps."""
    env = gym.make(f"observer_gym/{ENV}", obs_mode="measurements", **env_kwargs)
    try:
        obs, info = env.reset(seed=seed)
        observations, states = [obs], [info["state"]]
        for action in actions:
            obs, _, _, _, info = env.step(action)
            observations.append(obs)
            states.append(info["state"])
    finally:
        env.close()
    return {k: np.array([o[k] for o in observations]) for k in observations[0]}, np.array(states)


def one_line_error(capsys, argv: list[str]) -> tuple[int, str]:
    """The exit code and stderr of the command (a parse error exits with code 2)."""
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's mistakes: the parser's one line, code 2
        code = exc.code
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    return code, err


def episodes_id(out) -> str:
    """The dataset id of the recording in ``out``."""
    return recording_record(out)["dataset_id"]


def expected_draws() -> list[tuple[dict, int]]:
    """Each episode's options then world seed, drawn by hand from one generator."""
    rng = np.random.default_rng(SEED)
    draws = []
    for _ in range(EPISODES):
        options = {
            "latency_s": float(rng.uniform(0.0, 0.05)),
            "frame_drop_prob": float(rng.uniform(0.0, 0.2)),
            "calib_error_draw": ["per_episode", "fixed"][int(rng.integers(2))],
        }
        draws.append((options, int(rng.integers(WORLD_SEEDS_BELOW))))
    return draws


def test_each_episode_draws_its_options_then_its_seed_from_the_seed(recorded):
    out, record = recorded
    episodes = read_recording(out)
    assert len(episodes) == EPISODES
    for episode, played, (options, world_seed) in zip(
        episodes, record["episodes"], expected_draws(), strict=True
    ):
        assert episode.seed == played["seed"] == world_seed
        assert episode.drawn_options == options == played["drawn_options"]
    assert len({e.seed for e in episodes}) == EPISODES
    assert record["config"]["randomize"] == RANDOMIZE
    assert record["config"]["env_config"] is None  # each episode's own: drawn over FIXED


def test_minari_loads_the_drawn_options_in_the_episode_metadata(recorded, monkeypatch):
    out, record = recorded
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(out))
    dataset = minari.load_dataset(record["dataset_id"])
    metadata = list(dataset.storage.get_episode_metadata(range(EPISODES)))
    assert [m["seed"] for m in metadata] == [e["seed"] for e in record["episodes"]]
    assert [float(m["drawn_options"]["latency_s"]) for m in metadata] == [
        e["drawn_options"]["latency_s"] for e in record["episodes"]
    ]
    # the dataset's env spec holds the fixed options, not a draw
    spec = dataset.recover_environment(eval_env=True).spec
    assert spec.kwargs["measurement_noise_px"] == 0.5 and "latency_s" not in spec.kwargs


def test_the_seed_and_drawn_options_replay_each_episode(recorded):
    out, _ = recorded
    for episode in read_recording(out):
        options = {**FIXED, **episode.drawn_options}
        observations, states = replayed(options, episode.seed, episode.actions)
        for key, value in observations.items():
            np.testing.assert_array_equal(value, episode.observations[key])
        np.testing.assert_array_equal(states, episode.state)


@pytest.mark.parametrize(
    ("randomize", "env_kwargs", "message"),
    [
        ({"latency_s": {"low": 0.05, "high": 0.0}}, {}, "LOW=0.05 is above HIGH=0.0"),
        ({"nope": {"low": 0.0, "high": 1.0}}, {}, "has no option 'nope'; allowed: "),
        ({"latency_s": {"low": 0.0, "high": 1.0}}, {"latency_s": 0.1}, "also given as a fixed"),
        ({"frame_drop_prob": {"low": 0.0, "high": 1.5}}, {}, "frame_drop_prob=1.5"),
        ({"latency_s": {"low": 0.0}}, {}, "expected {'low': LOW, 'high': HIGH}"),
    ],
)
def test_a_bad_randomisation_is_refused_before_anything_runs(
    tmp_path, randomize, env_kwargs, message
):
    out = tmp_path / "dataset"
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace("{", r"\{")):
        record_experiment(
            ENV, OBSERVER, CONTROLLER, 1, 0, out, steps=2, progress=False,
            env_kwargs=env_kwargs, randomize=randomize,
        )  # fmt: skip
    assert not out.exists() and list(tmp_path.iterdir()) == []


ARGV = ["record", "--observer", OBSERVER, "--controller", CONTROLLER, "--episodes", "1"]


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--randomize", "latency_s=0.05:0"], "LOW=0.05 is above HIGH=0;"),
        (["--randomize", "latency_s=0:0.01", "--randomize", "latency_s=0:0.02"], "more than once"),
        (["--randomize", "latency_s=0:0.01", "--env-option", "latency_s=0.02"], "--env-option"),
        (["--randomize", "latency_s"], "expected KEY=LOW:HIGH"),
    ],
)
def test_the_command_refuses_a_bad_randomisation_in_one_line(tmp_path, capsys, extra, message):
    out = tmp_path / "dataset"
    code, err = one_line_error(capsys, [*ARGV, "--steps", "2", "--out", str(out), *extra])
    assert code == 2 and message in err and err.startswith("observer-gym record: error:")
    assert not out.exists()


def test_the_command_records_drawn_options(tmp_path, capsys):
    out = tmp_path / "dataset"
    argv = [*ARGV, "--steps", "2", "--out", str(out), "--no-progress"]
    assert main([*argv, "--seed", "3", "--randomize", "latency_s=0.01:0.02"]) == 0
    (episode,) = read_recording(out)
    assert set(episode.drawn_options) == {"latency_s"}
    assert 0.01 <= episode.drawn_options["latency_s"] <= 0.02


def test_the_union_of_spaces_holds_each_and_refuses_another_structure():
    low = gym.spaces.Dict(
        {"px": gym.spaces.Box(-1.0, 1.0, (2,), np.float64), "seen": gym.spaces.MultiBinary(1)}
    )
    high = gym.spaces.Dict(
        {"px": gym.spaces.Box(np.array([-3.0, 0.0]), np.array([0.5, 2.0]), dtype=np.float64)}
    )
    with pytest.raises(ValueError, match="different structure"):
        union_space([low, high])
    wide = gym.spaces.Dict(
        {
            "px": gym.spaces.Box(np.array([-3.0, 0.0]), np.array([0.5, 2.0]), dtype=np.float64),
            "seen": gym.spaces.MultiBinary(1),
        }
    )
    joined = union_space([low, wide])
    np.testing.assert_array_equal(joined["px"].low, [-3.0, -1.0])
    np.testing.assert_array_equal(joined["px"].high, [1.0, 2.0])
    assert joined["seen"] == gym.spaces.MultiBinary(1)
    with pytest.raises(ValueError, match="different structure"):  # no bounds: equal or refused
        union_space([gym.spaces.Discrete(2), gym.spaces.Discrete(3)])


def test_a_draw_that_widens_the_bounds_is_recorded_in_their_union(tmp_path):
    # TargetFollower's pixel bounds grow with measurement_noise_px
    out = tmp_path / "dataset"
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)  # Minari's "not in observation space"
        record_experiment(
            "TargetFollower-v0", "kf-measurements", "vtc", 3, 1, out, steps=3,
            progress=False, randomize={"measurement_noise_px": {"low": 0.0, "high": 5.0}},
        )  # fmt: skip
    episodes = read_recording(out)
    assert len({e.drawn_options["measurement_noise_px"] for e in episodes}) == 3
    space = minari.MinariDataset(out / episodes_id(out) / "data").observation_space
    bounds = [gym.make("observer_gym/TargetFollower-v0", obs_mode="measurements",
                       measurement_noise_px=p).observation_space["target_px"].high[0]
              for p in (0.0, 5.0)]  # fmt: skip
    assert bounds[1] > bounds[0]
    assert space["target_px"].high[0] == pytest.approx(bounds[1])


def test_the_python_function_randomizes_too(tmp_path):
    import observer_gym

    result = observer_gym.record(
        ENV, OBSERVER, CONTROLLER, episodes=2, seed=SEED, steps=2, out_dir=tmp_path / "r",
        randomize=RANDOMIZE, env_options=FIXED,
    )  # fmt: skip
    drawn = [e.drawn_options for e in read_recording(result.out_dir)]
    assert drawn == [options for options, _ in expected_draws()[:2]]
