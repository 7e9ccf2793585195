"""Controller fuzzing: ``make_controller(name, env, **options)`` with junk option values
(and unknown options), and ``predict`` with junk observations: each works (a finite
action within the bounds, of the observation's batch shape) or raises a ValueError."""

from __future__ import annotations

import inspect
import warnings

import gymnasium as gym
import numpy as np
import pytest
from fuzzlib import junk, numpy_arrays, record, special_floats
from hypothesis import given, note, settings
from hypothesis import strategies as st

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.controllers import make_controller
from observer_gym.controllers.registry import controllers_of
from observer_gym.envs import SYSTEMS

CONTROLLERS = [(system, name) for system in SYSTEMS for name in controllers_of(system)]
IDS = [name for _, name in CONTROLLERS]


@pytest.fixture(scope="module")
def envs():
    made: dict[str, gym.Env] = {}

    def get(system):
        if system.env_id not in made:
            made[system.env_id] = gym.make(system.env_id, obs_mode="state")
        return made[system.env_id]

    yield get
    for env in made.values():
        env.close()


def _option_values(name: str) -> st.SearchStrategy:
    number = st.one_of(
        st.floats(-1e3, 1e3), st.integers(-100, 100), special_floats(), st.floats(0.001, 10.0)
    )
    plausible = st.one_of(st.floats(0.01, 1.0), st.integers(1, 30), st.none(), st.booleans())
    return st.one_of(plausible, number, junk())


@pytest.mark.parametrize(("system", "name"), CONTROLLERS, ids=IDS)
@given(data=st.data())
@settings(max_examples=max(5, settings().max_examples // 2))
def test_make_controller_options(envs, system, name, data):
    env = envs(system)
    design = controllers_of(system)[name]
    allowed = list(inspect.signature(design.controller).parameters)[1:]
    unknown = st.text(max_size=8).filter(lambda k: k not in allowed)
    keys = st.one_of(
        st.sets(st.sampled_from(allowed), min_size=1, max_size=2),
        st.sets(st.sampled_from(allowed) | unknown, min_size=1, max_size=2),
    )
    keys_drawn = data.draw(keys, label="options")
    options = {k: data.draw(_option_values(k), label=k) for k in keys_drawn}
    category = f"make_controller: {name}"
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            controller = make_controller(name, env, **options)
    except ValueError as error:
        note(f"ValueError: {error}")
        record(category, accepted=False)
        message = str(error)
        assert any(k in message or repr(k) in message for k in options), message
        return
    record(category, accepted=True)
    obs = np.zeros(env.unwrapped.state_space.shape, np.float32)
    action, _ = controller.predict(obs)
    assert action.shape == env.action_space.shape and np.all(np.isfinite(action))


def _observations(n: int) -> st.SearchStrategy:
    finite = st.floats(-1e6, 1e6)
    return st.one_of(
        st.lists(finite, min_size=n, max_size=n).map(lambda v: (v, True)),
        st.lists(st.lists(finite, min_size=n, max_size=n), min_size=1, max_size=3).map(
            lambda v: (v, True)
        ),
        st.lists(st.floats(allow_nan=False, allow_infinity=False), min_size=n, max_size=n).map(
            lambda v: (v, True)  # huge but finite: the zero action where act overflows
        ),
        numpy_arrays((n,)).map(lambda v: (v, None)),
        junk().map(lambda v: (v, None)),
    )


@pytest.mark.parametrize(("system", "name"), CONTROLLERS, ids=IDS)
@given(data=st.data())
@settings(max_examples=max(5, settings().max_examples // 2))
def test_predict_observations(envs, system, name, data):
    env = envs(system)
    controller = make_controller(name, env)
    n = env.unwrapped.state_space.shape[0]
    obs, valid = data.draw(_observations(n), label="observation")
    category = f"predict: {name}"
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # overflow, singular B_i
            action, _ = controller.predict(obs)
    except ValueError as error:
        note(f"ValueError: {error}")
        record(category, accepted=False)
        assert valid is not True, f"a valid observation was refused: {error}"
        assert "predict: observation" in str(error)
        return
    record(category, accepted=True)
    batch = np.asarray(obs).ndim == 2
    space = env.action_space
    expected = (len(obs), *space.shape) if batch else space.shape
    assert action.shape == expected and np.all(np.isfinite(action))
    assert np.all(action >= space.low) and np.all(action <= space.high)
    kind = np.asarray(obs).dtype.kind
    assert kind in "biuf", f"an observation of dtype kind {kind!r} was taken: {obs!r}"
