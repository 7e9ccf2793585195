"""Action and reset-option fuzzing on every env (``gym.make``'d, obs_mode "state").

Each example runs two envs of the same seed: the fuzzed one gets junk mixed with valid
input, the reference only what the fuzzed one accepted. Every call either works or raises
a ValueError naming what was wrong; after a refused call the fuzzed env goes on exactly
as the reference (``info["state"]`` finite and equal): a refused call changed nothing.
"""

from __future__ import annotations

from collections.abc import Mapping

import gymnasium as gym
import numpy as np
import pytest
from fuzzlib import actions, junk, record
from gymnasium.utils.env_checker import data_equivalence
from hypothesis import given, note, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.envs import SYSTEMS

IDS = [s.short_id for s in SYSTEMS]
SEEDS = st.integers(0, 2**32 - 1)


@pytest.fixture(scope="module")
def env_pair():
    """``env_pair(system)`` -> (fuzzed env, reference env), made once per module."""
    made: dict[str, tuple[gym.Env, gym.Env]] = {}

    def get(system):
        if system.env_id not in made:
            made[system.env_id] = tuple(gym.make(system.env_id, obs_mode="state") for _ in range(2))
        return made[system.env_id]

    yield get
    for pair in made.values():
        for env in pair:
            env.close()


def _zero(env) -> np.ndarray:
    return np.zeros(env.action_space.shape, np.float32)


def _same_step(env, ref, action) -> None:
    got, want = env.step(action), ref.step(action)
    assert np.all(np.isfinite(got[4]["state"]))
    assert data_equivalence(got, want), "the fuzzed env left the reference's path"


# Each example resets (up to 0.15 s): half the profile's examples, several steps each.
ENV_EXAMPLES = settings(max_examples=max(5, settings().max_examples // 2))


@pytest.mark.parametrize("system", SYSTEMS, ids=IDS)
@given(seed=SEEDS, data=st.data())
@ENV_EXAMPLES
def test_actions(env_pair, system, seed, data):
    env, ref = env_pair(system)
    category = f"action: {system.short_id}"
    assert data_equivalence(env.reset(seed=seed), ref.reset(seed=seed))
    moves = data.draw(st.lists(actions(env.action_space.shape), min_size=1, max_size=8))
    for action, valid in moves:
        note(f"step({action!r}) expected {'valid' if valid else 'invalid'}")
        try:
            got = env.step(action)
        except ValueError as error:
            note(f"ValueError: {error}")
            record(category, accepted=False)
            assert not valid, f"a valid action was refused: {error}"
            assert "action" in str(error)
            continue
        record(category, accepted=True)
        assert valid, f"{action!r} was accepted"
        applied = got[4]["applied_action"]
        space = env.action_space
        assert applied.shape == space.shape and np.all(np.isfinite(applied))
        # within the bounds, up to rounding (TargetFollower reports the rates its drive
        # applied, 1 + 2e-16 for a commanded 1)
        low, high = space.low.astype(float), space.high.astype(float)
        slack = 1e-9 * np.maximum(1.0, np.abs(high))
        assert np.all(applied >= low - slack) and np.all(applied <= high + slack)
        want = ref.step(action)
        assert np.all(np.isfinite(got[4]["state"]))
        assert data_equivalence(got, want), "the fuzzed env left the reference's path"
    _same_step(env, ref, _zero(env))


# --- reset options ----------------------------------------------------------------------
def _vectors(n: int, bound: float) -> st.SearchStrategy:
    """n-vectors near the allowed bound (some beyond it), as lists or arrays."""
    values = st.floats(-1.5 * bound, 1.5 * bound)
    return st.one_of(
        st.lists(values, min_size=n, max_size=n),
        hnp.arrays(np.float64, (n,), elements=values),
        st.lists(values, min_size=n, max_size=n).map(lambda v: np.array(v, np.float32)),
    )


# per system: values of its reset options (a system not listed takes none)
OPTION_VALUES = {
    "ball_table": {
        "ball_pos_table_m": _vectors(2, 0.15),
        "ball_vel_table_mps": _vectors(2, 2.0),
    },
    "ball_catcher": {
        "throw": st.tuples(_vectors(3, 10.0), _vectors(3, 60.0)).map(list),
    },
    "target_follower": {
        "target_pos_world_m": _vectors(3, 50.0),
        "tilt_rad": st.floats(-1.5, 1.5) | st.floats(-1.5, 1.5).map(np.float32),
        "occlusions_s": st.lists(st.floats(-1.0, 4000.0), max_size=3),
    },
}


def _options(system) -> st.SearchStrategy:
    known = OPTION_VALUES.get(system.name, {})
    value_of = {k: st.one_of(v, junk(), st.none()) for k, v in known.items()}
    keys = st.text(max_size=10) | st.integers(-2, 2)
    if known:
        keys = st.sampled_from(sorted(known)) | keys
    as_dicts = st.dictionaries(keys, st.none(), max_size=3).flatmap(
        lambda d: st.fixed_dictionaries({k: value_of.get(k, junk()) for k in d})
    )
    return st.one_of(as_dicts, junk().filter(lambda v: not isinstance(v, Mapping)))


def _names_the_problem(message: str, options, known) -> bool:
    if not isinstance(options, Mapping):
        return "reset options must be a dict" in message
    return any((k in message if k in known else repr(k) in message) for k in options)


@pytest.mark.parametrize("system", SYSTEMS, ids=IDS)
@given(seeds=st.tuples(SEEDS, SEEDS, SEEDS), data=st.data())
@ENV_EXAMPLES
def test_reset_options(env_pair, system, seeds, data):
    env, ref = env_pair(system)
    category = f"reset options: {system.short_id}"
    first, second, third = seeds
    env.reset(seed=first)
    ref.reset(seed=first)
    _same_step(env, ref, _zero(env))
    options = data.draw(_options(system), label="options")
    try:
        got = env.reset(seed=second, options=options)
    except ValueError as error:
        note(f"ValueError: {error}")
        record(category, accepted=False)
        assert _names_the_problem(str(error), options, OPTION_VALUES.get(system.name, {})), str(
            error
        )
        # nothing changed: the episode goes on as the reference's
        _same_step(env, ref, _zero(env))
        assert data_equivalence(env.reset(seed=third), ref.reset(seed=third))
        _same_step(env, ref, _zero(env))
        return
    record(category, accepted=True)
    assert np.all(np.isfinite(got[1]["state"]))
    assert data_equivalence(got, ref.reset(seed=second, options=options))
    _same_step(env, ref, _zero(env))
