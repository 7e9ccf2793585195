"""Outside entries' failure modes, fuzzed: an outside observer's pipeline and an outside
controller (as the experiments drive them: CheckedPipeline, CheckedController) that raise
anything (sys.exit included), return junk or a covariance of any values, or write into
what they are shown.

Each call gives a checked result (a finite estimate with a covariance the NEES uses with
every degree of freedom; a finite action inside the action space) or a ValueError of one
line naming the entry; and what the env gave (the ground truth, the observation) is
unchanged either way.
"""

from __future__ import annotations

import copy

import gymnasium as gym
import numpy as np
import pytest
from fuzzlib import junk, numpy_arrays, record, special_floats
from hypothesis import given, settings
from hypothesis import strategies as st

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.estimation import Estimate, default_pipeline
from observer_gym.train.core import entries
from observer_gym.train.core.controller_entries import CheckedController
from observer_gym.train.core.entry_guard import CheckedPipeline

ENV = "observer_gym/BallTable-v0"
ERRORS = (RuntimeError, KeyError, ZeroDivisionError, AssertionError, TypeError, ValueError,
          RecursionError, OverflowError, AttributeError, IndexError)  # fmt: skip


def _plugin(kind: str) -> entries.Plugin:
    mode = "measurements" if kind == "observer" else None
    return entries.Plugin(kind, "fuzz", "fuzz:entry", mode, "python object", "fuzz", "0")


@pytest.fixture(scope="module")
def world():
    """(unwrapped env, obs, info, the kf's estimate) after a reset with seed 0."""
    env = gym.make(ENV, obs_mode="measurements").unwrapped
    obs, info = env.reset(seed=0)
    kf = default_pipeline(env, "kf")
    kf.reset()
    yield env, obs, info, kf.observe(obs, info, None)
    env.close()


def _fault():
    """What the entry does: (kind, payload)."""
    messages = st.text(max_size=20)
    return st.one_of(
        st.tuples(st.just("raise"), st.tuples(st.sampled_from(ERRORS), messages)),
        st.tuples(st.just("exit"), st.one_of(st.none(), st.integers(-3, 3), messages)),
        st.tuples(st.just("return"), junk()),
        st.tuples(st.just("covariance"), numpy_arrays(shape=(8, 8))),
        st.tuples(st.just("covariance"), st.floats(-1.0, 1.0)),
        st.tuples(st.just("write"), st.sampled_from(["state", "obs", "sensor", "unlock"])),
    )


def _behave(kind, payload, obs, info, good: Estimate):
    if kind == "raise":
        error, message = payload
        raise error(message)
    if kind == "exit":
        raise SystemExit(payload)
    if kind == "return":
        return payload
    if kind == "covariance":
        if isinstance(payload, float):  # correlation r between the first two entries
            P = np.eye(len(good.mean))
            P[0, 1] = P[1, 0] = payload
        else:
            P = payload
        return Estimate(good.mean.copy(), P, True, None, good.time_s)
    if payload == "state":
        info["state"][:] = 0.0
    elif payload == "obs":
        next(iter(obs.values()))[...] = 0.0
    elif payload == "sensor":
        info["sensor"] = None
    else:
        state = info["state"]
        state.flags.writeable = True
        state[:] = 0.0
    return good


@settings(max_examples=60)
@given(fault=_fault())
def test_an_observer_failing_any_way_is_one_line_and_changes_nothing(world, fault):
    _, obs, info, good = world
    before_info, before_obs = copy.deepcopy(info), copy.deepcopy(obs)

    class Entry:
        def reset(self):
            pass

        def observe(self, obs, info, action):
            return _behave(*fault, obs, info, good)

    checked = CheckedPipeline(Entry(), _plugin("observer"), len(good.mean))
    try:
        estimate = checked.observe(obs, info, None)
    except ValueError as exc:
        record(f"outside observer: {fault[0]}", False)
        assert str(exc).startswith("observer 'fuzz'") and "\n" not in str(exc)
    else:
        record(f"outside observer: {fault[0]}", True)
        assert estimate.mean.shape == good.mean.shape and np.isfinite(estimate.mean).all()
        P = estimate.covariance
        assert np.isfinite(P).all() and np.all(np.diag(P) > 0)
        assert np.linalg.eigvalsh(0.5 * (P + P.T)).min() > 0
    np.testing.assert_array_equal(info["state"], before_info["state"])
    assert info.keys() == before_info.keys()
    for key in obs:
        np.testing.assert_array_equal(obs[key], before_obs[key])


@settings(max_examples=60)
@given(
    action=st.one_of(
        junk(),
        numpy_arrays(shape=(2,)),
        st.lists(special_floats(), min_size=2, max_size=2),
        st.floats(allow_nan=False).map(lambda v: [v, -v]),
    ),
    fault=st.sampled_from(["none", "raise", "exit", "write"]),
)
def test_a_controller_failing_any_way_is_one_line_and_acts_inside_the_space(world, action, fault):
    env, _, info, _ = world
    state = np.asarray(info["state"], dtype=float)
    before = state.copy()

    class Entry:
        def predict(self, observation, state=None, episode_start=None, deterministic=True):
            if fault == "raise":
                raise RuntimeError("diverged")
            if fault == "exit":
                raise SystemExit(0)
            if fault == "write":
                observation[...] = 0.0
            return action, state

    checked = CheckedController.__new__(CheckedController)
    checked.controller, checked.name = Entry(), "fuzz"
    checked._space = env.action_space
    try:
        applied, _ = checked.predict(state)
    except ValueError as exc:
        record(f"outside controller: {fault}", False)
        assert str(exc).startswith("controller 'fuzz'") and "\n" not in str(exc)
    else:
        record(f"outside controller: {fault}", True)
        space = env.action_space
        assert applied.shape == space.shape and np.isfinite(applied).all()
        assert np.all(applied >= space.low) and np.all(applied <= space.high)
    np.testing.assert_array_equal(state, before)
