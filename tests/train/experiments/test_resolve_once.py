"""A request is resolved once (issue 44): one small compare looks its system and its
task up once per process and each observer once, a controller's design once per episode;
the episode specs carry the resolved System and entries, pickle, and an episode run from
a pickled spec (as a worker or a Ray task runs it) looks no name up."""

from __future__ import annotations

import cProfile
import dataclasses
import pickle
import pstats
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from outside_package import PACKAGE

import observer_gym
from observer_gym.train.core.tasks import ball_table
from observer_gym.train.experiments.episode import EpisodeSpec, run_episode, run_episodes
from observer_gym.train.experiments.request import resolve_request
from observer_gym.train.reports import compare_report

ENV = "BallTable-v0"
# the look-ups by name, and the env builds, counted by their functions' names
COUNTED = (
    "system_for_id",
    "task_of",
    "controllers_of",
    "observer_setup",  # main's per-call observer look-up (gone: a count of 0)
    "resolve_observer",
    "make_env",
)


def _calls(function: Callable[[], Any]) -> dict[str, int]:
    """How many times ``function`` calls each of :data:`COUNTED` (cProfile counts every
    call of the package's functions, wherever a module imported them by name)."""
    profile = cProfile.Profile()
    profile.enable()
    try:
        function()
    finally:
        profile.disable()
    counts = dict.fromkeys(COUNTED, 0)
    stats: dict = pstats.Stats(profile).stats  # type: ignore[attr-defined]
    for (path, _line, name), (_primitive, calls, *_rest) in stats.items():
        if name in counts and "/tests/" not in path:
            counts[name] += calls
    return counts


@pytest.fixture
def no_plots(monkeypatch):
    """Skip drawing (most of a short comparison's time)."""
    monkeypatch.setattr(compare_report, "plot_bars", lambda *args, **kwargs: None)
    monkeypatch.setattr(ball_table, "plot", lambda records, observer, out_dir: [])


def test_one_small_compare_resolves_its_system_and_task_once(tmp_path, no_plots):
    episodes = 2  # two observers, one controller, one seed
    calls = _calls(
        lambda: observer_gym.compare(
            env=ENV,
            observers=["kf-measurements", "oracle"],
            controllers=["lqr"],
            seeds=[0],
            steps=5,
            out_dir=tmp_path / "out",
        )
    )
    # at main 2535b5c: system_for_id 5, task_of 20, controllers_of 13, observer_setup 12
    assert calls["system_for_id"] == 1
    assert calls["task_of"] == 1
    assert calls["observer_setup"] == 0
    # each observer once, and the oracle once more for the designs' check on the state env
    assert calls["resolve_observer"] == 3
    # the request's controllers, the designs' check, then once per episode spec
    assert calls["controllers_of"] == 2 + episodes
    # the designs' check, then one env per episode
    assert calls["make_env"] == 1 + episodes


def test_a_spec_pickles_and_its_episode_looks_no_name_up():
    request = resolve_request(ENV, ["kf-measurements"], ["lqr"], [3], steps=5)
    spec = EpisodeSpec.of_entries(
        request.system, request.observers[0], request.controllers[0], 3, max_steps=5
    )
    # the names given to EpisodeSpec.of resolve to the same spec
    assert EpisodeSpec.of(ENV, "kf-measurements", "lqr", 3, max_steps=5) == spec
    travelled = pickle.loads(pickle.dumps(spec))
    assert travelled == spec and travelled.env_id == "observer_gym/BallTable-v0"
    records = []
    calls = _calls(lambda: records.append(run_episode(travelled)))
    assert calls["system_for_id"] == calls["task_of"] == calls["resolve_observer"] == 0
    assert calls["controllers_of"] == 1  # the lqr's design, once for the episode
    assert calls["make_env"] == 1
    here = run_episode(spec)
    np.testing.assert_array_equal(records[0]["state"], here["state"])
    np.testing.assert_array_equal(records[0]["actions"], here["actions"])
    assert len(here["actions"]) == 5


def _outside_specs() -> list[EpisodeSpec]:
    """Two 5-step episodes of the outside alpha-beta observer (alpha 0.4) with the lqr."""
    observer = f"{PACKAGE}.filters:make_observer-measurements"
    request = resolve_request(
        ENV, [observer], ["lqr"], [0, 1], steps=5, observer_options={"alpha": 0.4}
    )
    entry = request.observers[0]
    assert entry.plugin is not None and entry.options == {"alpha": 0.4}
    assert entry.obs_mode == "measurements"
    return [
        EpisodeSpec.of_entries(request.system, entry, request.controllers[0], seed, max_steps=5)
        for seed in request.seeds
    ]


def test_an_outside_entry_travels_resolved_with_its_options(outside):
    specs = _outside_specs()
    travelled = [pickle.loads(pickle.dumps(spec)) for spec in specs]
    assert travelled == specs
    (mine,) = run_episodes(travelled[:1], workers=1, progress=False)
    # the options reached the factory: another alpha gives other estimates
    entry = specs[0].observer.with_options({"alpha": 0.9})
    (other,) = run_episodes([dataclasses.replace(specs[0], observer=entry)], progress=False)
    assert np.isfinite(mine["estimate"]).all()
    assert not np.array_equal(other["estimate"], mine["estimate"])


@pytest.mark.slow  # two spawned worker processes
def test_an_outside_entry_s_specs_run_in_workers_as_here(outside):
    specs = _outside_specs()
    here = run_episodes(specs, workers=1, progress=False)
    spawned = run_episodes(specs, workers=2, progress=False)  # pickled to two processes
    for mine, theirs in zip(here, spawned, strict=True):
        np.testing.assert_array_equal(mine["estimate"], theirs["estimate"])
        np.testing.assert_array_equal(mine["actions"], theirs["actions"])
