"""``observer-gym train --randomize``: each training episode draws the named env options
(reproducibly from the seed, differently per episode, inside the ranges), builds its world
with them, records them in config.json, keeps them on resume, and leaves the evaluation
and every loaded agent on the fixed options."""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
import pytest
from stable_baselines3 import PPO

from observer_gym.envs import system_for_id
from observer_gym.train.cli import main
from observer_gym.train.core.observer_env import make_env, resolve_observer
from observer_gym.train.rl import randomize as randomize_module
from observer_gym.train.rl.agent import Agent
from observer_gym.train.rl.agent_env import make_agent_env
from observer_gym.train.rl.randomize import (
    RandomizedEnv,
    check_randomize,
    draw_options,
    parse_randomize_text,
)
from observer_gym.train.rl.seeds import train_seeds
from observer_gym.train.rl.training import resume_training, train_agent

ENV = "observer_gym/BallCatcher-v1"
# BallCatcher's sensor from the suite's ideal level to its field level (part of it)
RANGES = {
    "latency_s": {"low": 0.0, "high": 0.01},
    "measurement_noise_px": {"low": 0.5, "high": 2.0},
    "frame_drop_prob": {"low": 0.0, "high": 0.1},
    "camera_preset": {"choices": ["alternating", "random_offsets"]},
    "air_drag": {"choices": [False, True]},
}
FIXED = {"shaping_weight": 5.0}
# 2 in-process envs, rollouts of 2 x 128 steps, evaluation and checkpoints every 256 steps
SMALL = {
    "n_envs": 2,
    "vec_env": "dummy",
    "hyperparams": {
        "n_steps": 128,
        "batch_size": 64,
        "eval_freq": 256,
        "eval_episodes": 1,
        "checkpoint_freq": 256,
    },
}


def _env(randomize=RANGES) -> RandomizedEnv:
    env = make_agent_env(
        ENV, "estimate", "measurements", FIXED, None, None, "crossing", dict(randomize)
    )
    assert isinstance(env, RandomizedEnv)
    return env


def _episode_options(env: RandomizedEnv, seed: int, episodes: int) -> list[dict]:
    """The options of ``episodes`` resets (the first seeded), as the inner worlds hold them."""
    seen = []
    for k in range(episodes):
        _, info = env.reset(seed=seed if k == 0 else None)
        config = env.inner.unwrapped.config
        assert info["randomized"] == env.options
        seen.append({key: getattr(config, key) for key in RANGES})
    return seen


def test_the_draws_repeat_with_the_seed_and_differ_between_episodes():
    first, second, other = _env(), _env(), _env()
    try:
        a = _episode_options(first, 1_000_000, 4)
        b = _episode_options(second, 1_000_000, 4)
        c = _episode_options(other, 1_000_001, 4)
    finally:
        for env in (first, second, other):
            env.close()
    assert a == b  # the same seed, the same options episode after episode
    assert a != c  # another seed (another rank or run), other draws
    for earlier, later in itertools.pairwise(a):
        assert earlier["latency_s"] != later["latency_s"]
        assert earlier["measurement_noise_px"] != later["measurement_noise_px"]


def test_every_draw_is_inside_its_range_and_every_choice_comes_up():
    rng = np.random.default_rng(7)
    draws = [draw_options(RANGES, rng) for _ in range(400)]
    for key, spec in RANGES.items():
        values = [d[key] for d in draws]
        if "choices" in spec:
            assert set(values) == set(spec["choices"])  # each of them, none else
        else:
            assert min(values) >= spec["low"] and max(values) <= spec["high"]
            # spread over the range, not stuck at an end
            assert max(values) - min(values) > 0.9 * (spec["high"] - spec["low"])
    # an integer option draws integers, both ends included
    ints = [
        draw_options({"num_cameras": {"low": 1, "high": 2}}, rng, frozenset({"num_cameras"}))
        for _ in range(50)
    ]
    assert {d["num_cameras"] for d in ints} == {1, 2}


def test_each_episode_is_a_new_world_with_the_drawn_options():
    env = _env()
    try:
        env.reset(seed=5)
        worlds = []
        for _ in range(3):
            _, info = env.reset()
            inner = env.inner.unwrapped
            worlds.append(inner)
            drawn = env.options
            # the world's options and the sensor it declares are the drawn ones
            for key, value in drawn.items():
                assert getattr(inner.config, key) == value, key
            assert inner.sensor_spec.latency_s == drawn["latency_s"]
            assert inner.sensor_spec.measurement_noise_px == drawn["measurement_noise_px"]
            assert info["sensor"].frame_drop_prob == drawn["frame_drop_prob"]
            assert inner.config.shaping_weight == FIXED["shaping_weight"]  # fixed ones kept
            env.step(env.action_space.sample())
        assert len({id(world) for world in worlds}) == 3
        assert env.episodes == 5  # built at construction, then at every reset
    finally:
        env.close()
    assert env.inner is None


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("latency_s", "expected KEY=LOW:HIGH"),
        ("latency_s=0.02:0.01", "LOW=0.02 is above HIGH=0.01"),
        ("latency_s=a:0.01", "LOW and HIGH must be numbers"),
        ("latency_s=0:nan", "must be finite numbers"),
        ("air_drag=True|True", "listed twice"),
        ("2x=0:1", "expected KEY=LOW:HIGH"),
    ],
)
def test_a_bad_form_is_a_value_error_naming_it(text, message):
    with pytest.raises(ValueError, match=message):
        parse_randomize_text(text)


def test_the_forms_read_numbers_and_choices():
    assert parse_randomize_text("latency_s=0:0.01") == ("latency_s", {"low": 0, "high": 0.01})
    assert parse_randomize_text("air_drag=False|True") == ("air_drag", {"choices": [False, True]})
    assert parse_randomize_text("camera_preset=alternating|random_offsets") == (
        "camera_preset",
        {"choices": ["alternating", "random_offsets"]},
    )


@pytest.mark.parametrize(
    ("randomize", "fixed", "message"),
    [
        ({"latency": {"low": 0, "high": 1}}, None, "has no option 'latency'; allowed: .*latency_s"),
        ({"latency_s": {"low": 0, "high": 0.9}}, None, r"latency_s=0.9.*allowed: \[0.0, 0.5\]"),
        ({"latency_s": {"low": -0.1, "high": 0}}, None, r"latency_s=-0.1 is out of range"),
        ({"camera_preset": {"low": 0, "high": 1}}, None, "is no number"),
        ({"camera_preset": {"choices": ["alternating", "x"]}}, None, "choose one of"),
        ({"num_cameras": {"low": 0, "high": 1.5}}, None, "LOW and HIGH must be integers"),
        ({"obs_mode": {"choices": ["rgb"]}}, None, "not an option"),
        ({"latency_s": {"low": 0, "high": 0.01}}, {"latency_s": 0.0}, "also given as a fixed"),
        (
            {"flight_time_min_s": {"low": 0.4, "high": 0.6}},
            None,
            "flight_time_min_s=0.6 must be <= flight_time_max_s",
        ),
    ],
)
def test_the_library_refuses_what_the_env_does_not_take(randomize, fixed, message):
    with pytest.raises(ValueError, match=message):
        check_randomize(ENV, "measurements", FIXED, randomize, fixed=fixed)


def _config(run: Path) -> dict:
    return json.loads((run / "config.json").read_text())


@pytest.fixture(scope="module")
def counted(request):
    """Every RandomizedEnv built and every world it rebuilt, in this process."""
    built: list[RandomizedEnv] = []
    original = RandomizedEnv.__init__
    monkeypatch = pytest.MonkeyPatch()

    def init(self, *args, **kwargs):
        original(self, *args, **kwargs)
        built.append(self)

    monkeypatch.setattr(RandomizedEnv, "__init__", init)
    request.addfinalizer(monkeypatch.undo)
    return built


@pytest.fixture(scope="module")
def randomized(tmp_path_factory, counted) -> tuple[Path, list[RandomizedEnv]]:
    """A 256-step randomised PPO run on BallCatcher (seed 3) and the envs it built."""
    out = tmp_path_factory.mktemp("rand") / "run"
    before = len(counted)
    state = train_agent(
        ENV,
        "ppo",
        "estimate",
        out,
        timesteps=256,
        seed=3,
        randomize=RANGES,
        progress=False,
        **SMALL,
    )
    assert state["status"] == "finished"
    return out, counted[before:]


@pytest.fixture(scope="module")
def randomized_run(randomized) -> Path:
    return randomized[0]


def test_the_run_records_its_randomisation_and_trains_only_on_it(randomized):
    randomized_run, counted = randomized
    config = _config(randomized_run)
    assert config["randomize"] == RANGES
    assert config["env_kwargs"] == FIXED  # the fixed options, which loading uses
    # the two training envs randomise; the evaluation env (fixed options) does not
    assert len(counted) == 2
    assert all(env.episodes >= 3 for env in counted)  # a new world at every episode
    for env in counted:
        for key, spec in RANGES.items():
            value = env.options[key]
            assert (
                value in spec["choices"]
                if "choices" in spec
                else spec["low"] <= value <= spec["high"]
            )


def test_a_loaded_agent_reads_the_fixed_options(randomized_run):
    agent = Agent.load(randomized_run)
    env = agent.wrap_env(
        make_env(
            system := system_for_id(agent.config["env_id"]),
            resolve_observer(system, agent.config["observer"]),
            agent.config["env_kwargs"],
        )
    )
    try:
        observation, _ = env.reset(seed=0)
        config = env.unwrapped.config
        assert (config.latency_s, config.camera_preset, config.air_drag) == (
            0.0,
            "alternating",
            False,
        )
        agent.predict(observation)
    finally:
        env.close()


def test_resume_keeps_the_randomisation(randomized_run, counted, tmp_path):
    run = tmp_path / "run"
    import shutil

    shutil.copytree(randomized_run, run)
    before = len(counted)
    state = resume_training(run, timesteps=512, progress=False)
    assert state["status"] == "finished" and state["timesteps"] == 512
    assert _config(run)["randomize"] == RANGES
    resumed = counted[before:]
    assert len(resumed) == 2 and all(env.randomize == RANGES for env in resumed)
    assert all(env.episodes >= 3 for env in resumed)


@pytest.mark.slow  # three trainings (44 s at load 7)
def test_a_seed_of_a_randomised_multi_seed_run_equals_its_single_run(randomized_run, tmp_path):
    result = train_seeds(
        ENV,
        "ppo",
        "estimate",
        tmp_path / "seeds",
        (2, 3),
        workers=2,
        progress=False,
        reps=100,
        timesteps=256,
        randomize=RANGES,
        **SMALL,
    )
    assert result.status == "finished"
    together = tmp_path / "seeds" / "seed_3"
    assert _config(together)["randomize"] == RANGES
    for a, b in zip(
        PPO.load(randomized_run / "model.zip").policy.parameters(),
        PPO.load(together / "model.zip").policy.parameters(),
        strict=True,
    ):
        np.testing.assert_array_equal(a.detach().numpy(), b.detach().numpy())


def test_without_randomize_the_env_is_the_plain_one():
    env = make_agent_env(ENV, "estimate", "measurements", FIXED, None, None, "crossing", None)
    try:
        assert not isinstance(env, RandomizedEnv)
    finally:
        env.close()


def test_train_help_names_the_forms(capsys):
    with pytest.raises(SystemExit):
        main(["train", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "KEY=LOW:HIGH a number uniform in [LOW, HIGH]" in text
    assert "KEY=A|B|... one of the values" in text


def test_the_module_imports_no_pytorch():
    import subprocess
    import sys

    probe = (
        "import sys, observer_gym.train.rl.randomize as r; "
        "r.check_randomize('BallCatcher-v1', 'measurements', {}, "
        "{'latency_s': {'low': 0, 'high': 0.01}}); print('torch' in sys.modules)"
    )
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True)
    assert result.stdout.strip() == "False", result.stderr
    assert randomize_module.FORMS in parse_randomize_text.__globals__["FORMS"]
