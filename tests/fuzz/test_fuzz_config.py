"""Config fuzzing: every value of every field of every env's config dataclass (strategies
derived from ``config_field``'s metadata, so a new field is covered without a change here)
either constructs, stored as a Python value equal to the given one, or raises a ValueError
naming the field. A few valid combinations build real envs that reset and step."""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math

import gymnasium as gym
import numpy as np
import pytest
from fuzzlib import field_values, junk, record
from hypothesis import assume, given, note, settings
from hypothesis import strategies as st

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.envs import SYSTEMS

CONFIGS = {system.short_id: system.env_class().config_class for system in SYSTEMS}
FIELDS = [(env, field) for env, config in CONFIGS.items() for field in dataclasses.fields(config)]


_field_values = functools.cache(field_values)


def _check(config_class, kwargs: dict, named: set[str], category: str):
    """Build ``config_class`` from ``kwargs``: the config, or None after a ValueError
    naming one of ``named``; any other exception fails."""
    note(f"{config_class.__name__}.from_kwargs(**{kwargs!r})")
    try:
        config = config_class.from_kwargs(**kwargs)
    except ValueError as error:
        message = str(error)
        note(f"ValueError: {message}")
        assert any(name in message for name in named), f"{message!r} names none of {named}"
        record(category, accepted=False)
        return None
    record(category, accepted=True)
    return config


def _same_value(stored, given) -> bool:
    if isinstance(stored, bool):
        return stored == bool(given)
    if isinstance(stored, int):
        return stored == int(given)
    if isinstance(stored, float):
        return stored == float(given)
    return stored == given


@pytest.mark.parametrize(("env", "field"), FIELDS, ids=[f"{e}.{f.name}" for e, f in FIELDS])
@given(data=st.data())
@settings(max_examples=max(5, settings().max_examples // 4))
def test_one_field(env, field, data):
    config_class = CONFIGS[env]
    value, valid = data.draw(_field_values(field), label=field.name)
    config = _check(config_class, {field.name: value}, {field.name}, f"config field: {env}")
    if config is None:
        # a value the field allows may still break a rule between fields (e.g.
        # frame_phase_s below one frame period): that message names the field too
        return
    assert valid, f"{field.name}={value!r} was accepted"
    stored = getattr(config, field.name)
    assert type(stored) in (int, float, bool, str), type(stored)
    assert type(stored) is type(field.default) or field.metadata["choices"] is not None
    assert _same_value(stored, value)


@functools.cache
def _kwargs(config_class) -> st.SearchStrategy:
    """Several fields at once: dicts of (value, valid) per field name."""
    fields = {f.name: _field_values(f) for f in dataclasses.fields(config_class)}
    return st.dictionaries(
        st.sampled_from(sorted(fields)), st.just(None), min_size=1, max_size=6
    ).flatmap(lambda keys: st.fixed_dictionaries({k: fields[k] for k in keys}))


@pytest.mark.parametrize("env", list(CONFIGS))
@given(data=st.data())
def test_many_fields(env, data):
    config_class = CONFIGS[env]
    drawn = data.draw(_kwargs(config_class))
    kwargs = {name: value for name, (value, _) in drawn.items()}
    invalid = {name for name, (_, valid) in drawn.items() if not valid}
    config = _check(config_class, kwargs, set(kwargs), f"config fields: {env}")
    if config is not None:
        assert not invalid, f"{sorted(invalid)} accepted"
        for name, value in kwargs.items():
            assert _same_value(getattr(config, name), value), name


@pytest.mark.parametrize("env", list(CONFIGS))
@given(key=st.text(max_size=20), value=junk())
def test_unknown_keywords(env, key, value):
    config_class = CONFIGS[env]
    assume(key not in {f.name for f in dataclasses.fields(config_class)})
    with pytest.raises(ValueError, match="has no option") as raised:
        config_class.from_kwargs(**{key: value})
    assert repr(key) in str(raised.value)
    record(f"config unknown keyword: {env}", accepted=False)


@functools.cache
def _valid_kwargs(config_class) -> st.SearchStrategy:
    return _kwargs(config_class).map(
        lambda drawn: {k: v for k, (v, valid) in drawn.items() if valid}
    )


@pytest.mark.parametrize("system", SYSTEMS, ids=[s.short_id for s in SYSTEMS])
@given(data=st.data())
@settings(max_examples=max(2, settings().max_examples // 8))
def test_real_envs_from_valid_configs(system, data):
    """A valid config builds an env (obs_mode "state" or "measurements", small images, to
    stay fast) whose reset and steps give a finite state."""
    config_class = CONFIGS[system.short_id]
    kwargs = data.draw(_valid_kwargs(config_class))
    kwargs["obs_mode"] = data.draw(st.sampled_from(["state", "measurements"]))
    kwargs["image_width_px"], kwargs["image_height_px"] = 64, 48
    config = _check(config_class, kwargs, set(kwargs), f"gym.make: {system.short_id}")
    assume(config is not None)
    env = gym.make(system.env_id, **kwargs)
    try:
        _, info = env.reset(seed=data.draw(st.integers(0, 2**32 - 1)))
        assert np.all(np.isfinite(info["state"]))
        for _ in range(3):
            *_, info = env.step(env.action_space.sample())
            assert np.all(np.isfinite(info["state"]))
    finally:
        env.close()
    assert math.isfinite(config.frame_rate_hz)


def _numeric_fields(config_class) -> list[dataclasses.Field]:
    return [
        f
        for f in dataclasses.fields(config_class)
        if isinstance(f.default, int | float)
        and not isinstance(f.default, bool)
        and f.metadata["low"] is not None
        and f.metadata["high"] is not None
        and f.name not in getattr(config_class, "discrete_options", {})
    ]


@st.composite
def _box(draw, config_class) -> dict:
    """A randomisation of 1-4 numeric options: a range inside each field's bounds; the
    fields either any of the config's or those sharing a word (flight_time_min_s and
    flight_time_max_s, launch_*, start_*), which the rules between options tie."""
    fields = _numeric_fields(config_class)
    groups: dict[str, list] = {}
    for f in fields:
        groups.setdefault(f.name.split("_")[0], []).append(f)
    tied = [group for group in groups.values() if len(group) > 1]
    if tied and draw(st.booleans()):
        pool = draw(st.sampled_from(tied))
        size = st.integers(2, min(4, len(pool)))
        chosen = draw(size.flatmap(lambda n: st.permutations(pool).map(lambda p: p[:n])))
    else:
        chosen = draw(st.lists(st.sampled_from(fields), min_size=1, max_size=4, unique_by=id))
    box = {}
    for f in chosen:
        low, high = f.metadata["low"], f.metadata["high"]
        if isinstance(f.default, int):
            ends = sorted(draw(st.lists(st.integers(low, high), min_size=2, max_size=2)))
        else:  # anywhere in the field's range, or near its default (where rules bind)
            default = f.default
            near = st.floats(default - 0.3 * abs(default), default + 0.3 * abs(default))
            value = st.one_of(st.floats(low, high), near.filter(lambda v: low <= v <= high))  # noqa: B023
            ends = sorted(draw(st.lists(value, min_size=2, max_size=2)))
        box[f.name] = {"low": ends[0], "high": ends[1]}
    return box


@pytest.mark.parametrize("system", SYSTEMS, ids=[s.short_id for s in SYSTEMS])
@given(data=st.data())
def test_every_draw_of_a_checked_randomisation_builds(system, data):
    """``train --randomize``'s check (every corner of the box) covers every draw inside
    it: a randomisation it takes never draws options the env refuses (each rule between
    options is monotone in each, see train/rl/randomize.py)."""
    from observer_gym.train.rl.randomize import check_randomize, draw_options, integer_options

    config_class = CONFIGS[system.short_id]
    box = data.draw(_box(config_class), label="randomize")
    try:
        checked = check_randomize(system.env_id, "state", {}, box)
    except ValueError as error:
        assert any(name in str(error) for name in box), str(error)
        record(f"randomize: {system.short_id}", accepted=False)
        return
    record(f"randomize: {system.short_id}", accepted=True)
    # the grid of each range's ends and middle (a draw can take each), then random draws
    integers = integer_options(system.env_id)
    grid = [
        [s["low"], s["high"], (s["low"] + s["high"]) // 2 if k in integers else
         (s["low"] + s["high"]) / 2]
        for k, s in checked.items()
    ]  # fmt: skip
    points = [dict(zip(checked, p, strict=True)) for p in itertools.product(*grid)]
    rng = np.random.default_rng(data.draw(st.integers(0, 2**32 - 1), label="seed"))
    for drawn in points + [draw_options(checked, rng, integers) for _ in range(200)]:
        note(f"drawn {drawn}")
        config_class.from_kwargs(obs_mode="state", **drawn)
