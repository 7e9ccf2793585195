"""Observer fuzzing: every system's default pipeline (what ``VisionObserver`` runs,
``pipeline.observe(obs, info, action)``) fed junk measurements and frames over a recorded
episode: NaN, inf, huge values, wrong shapes and dtypes, missing keys, other types.

Each call gives a finite estimate of the state's shape, or a ValueError. A reference
pipeline gets the same input whenever the fuzzed one accepts it; after a ValueError the
fuzzed pipeline gets the step's real input again, and its estimate must equal the
reference's: a refused input changed nothing.
"""

from __future__ import annotations

import copy

import gymnasium as gym
import numpy as np
import pytest
from fuzzlib import junk, record, special_floats
from hypothesis import given, note, settings
from hypothesis import strategies as st

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.envs import SYSTEMS
from observer_gym.estimation import default_pipeline

IDS = [s.short_id for s in SYSTEMS]
MODES = ("measurements", "rgb")
STEPS = 6
SIZE = {"image_width_px": 64, "image_height_px": 48}


@pytest.fixture(scope="module")
def recorded():
    """``recorded(system, mode)`` -> (unwrapped env, [(obs, info, action)] of one episode
    at random actions, seed 0); the env stays open for its pipelines."""
    made: dict[tuple[str, str], tuple] = {}

    def get(system, mode):
        key = (system.env_id, mode)
        if key not in made:
            env = gym.make(system.env_id, obs_mode=mode, **SIZE).unwrapped
            env.action_space.seed(0)
            obs, info = env.reset(seed=0)
            episode = [(obs, info, None)]
            for _ in range(STEPS):
                action = env.action_space.sample()
                obs, *_, info = env.step(action)
                episode.append((obs, info, info["applied_action"]))
            made[key] = (env, episode)
        return made[key]

    yield get
    for env, _ in made.values():
        env.close()


def _measurement_slots(system, mode, obs, info):
    """Where the step's measurement lives: (container, key) pairs to fuzz."""
    if system.name == "ball_catcher":
        key = "image" if mode == "rgb" else "uv_px"
        return [(frame, key) for frame in info["frames"]]
    return [("obs", None)]


def _junk_for(original, data) -> object:
    """A junk replacement for one measurement value or frame."""
    kind = data.draw(st.sampled_from(["junk", "special", "dtype", "shape", "noise", "drop"]))
    note(f"fuzz: {kind}")
    if kind == "drop":
        return _DROP
    if isinstance(original, dict) and kind != "junk":
        key = data.draw(st.sampled_from(sorted(original)))
        changed = dict(original)
        value = _junk_for(original[key], data)
        if value is _DROP:
            del changed[key]
        else:
            changed[key] = value
        return changed
    array = np.asarray(original)
    if kind == "special" and array.size and array.dtype.kind == "f":
        array = array.astype(np.float64)
        index = data.draw(st.integers(0, array.size - 1))
        array.flat[index] = data.draw(special_floats())
        return array
    if kind == "dtype":
        dtype = data.draw(
            st.sampled_from(
                [
                    np.float16,
                    np.float32,
                    np.int64,
                    np.uint8,
                    np.bool_,
                    np.complex128,
                    np.str_,
                    object,
                ]
            )
        )
        try:
            with np.errstate(all="ignore"):
                return array.astype(dtype)
        except (TypeError, ValueError):  # e.g. None (no detection) as an int
            return data.draw(junk())
    if kind == "shape":
        shape = data.draw(st.lists(st.integers(0, 4), max_size=3).map(tuple))
        return np.zeros(shape, array.dtype)
    if kind == "noise" and array.dtype == np.uint8:
        rng = np.random.default_rng(data.draw(st.integers(0, 2**32 - 1)))
        return rng.integers(0, 256, array.shape, dtype=np.uint8)  # a valid frame of noise
    return data.draw(junk())


_DROP = object()


def _fuzzed(system, mode, obs, info, data):
    """(obs, info) with one measurement slot replaced by junk (deep copies)."""
    obs, info = copy.deepcopy(obs), copy.deepcopy(info)
    slots = _measurement_slots(system, mode, obs, info)
    if not slots:
        return obs, info
    container, key = data.draw(st.sampled_from(slots))
    if container == "obs":
        value = _junk_for(obs, data)
        return (None if value is _DROP else value), info
    value = _junk_for(container[key], data)
    if value is _DROP:
        del container[key]
    else:
        container[key] = value
    return obs, info


def _assert_finite(estimate, n: int) -> None:
    assert estimate.mean.shape == (n,) and estimate.covariance.shape == (n, n)
    assert np.all(np.isfinite(estimate.mean)) and np.all(np.isfinite(estimate.covariance))


def _same(a, b) -> None:
    np.testing.assert_array_equal(a.mean, b.mean)
    np.testing.assert_array_equal(a.covariance, b.covariance)
    assert a.measurement_used == b.measurement_used


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("system", SYSTEMS, ids=IDS)
@given(data=st.data())
@settings(max_examples=max(5, settings().max_examples // 2))
def test_observer_inputs(recorded, system, mode, data):
    env, episode = recorded(system, mode)
    n = env.state_space.shape[0]
    pipeline, reference = default_pipeline(env), default_pipeline(env)
    category = f"observer {mode}: {system.short_id}"
    bad_steps = data.draw(st.sets(st.integers(0, STEPS), min_size=1, max_size=3), label="steps")
    for k, (obs, info, action) in enumerate(episode):
        if k in bad_steps:
            bad_obs, bad_info = _fuzzed(system, mode, obs, info, data)
            try:
                got = pipeline.observe(bad_obs, bad_info, action)
            except ValueError as error:
                note(f"step {k}: ValueError: {error}")
                record(category, accepted=False)
                assert str(error)
            else:
                record(category, accepted=True)
                _assert_finite(got, n)
                _same(got, reference.observe(bad_obs, bad_info, action))
                continue
        got = pipeline.observe(obs, info, action)
        _assert_finite(got, n)
        _same(got, reference.observe(obs, info, action))
