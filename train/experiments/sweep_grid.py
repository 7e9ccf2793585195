"""The grid of ``observer-gym sweep``: the env options that vary and their values.

A key is a field of the env's configuration class (``BallTableConfig`` ...; every env
option but ``obs_mode``, which each observer decides). Values given as text (the command
line's ``--vary KEY=V1,V2``) are read as the field's type: a number, an integer, true or
false, or text. :func:`check_grid` then builds the env's configuration for every grid
point with every observer's ``obs_mode``, so the configuration's own checks (its ranges,
its choices, the checks between options) name what is allowed before anything runs.

The grid is the cartesian product of the keys' values, the first key outermost. This
module is light: it imports the env's module (for its configuration class) and builds no
world, so the command checks a sweep before its heavy imports.

Which sensor options change the world (:func:`world_draw_notes`): the sensor draws from
streams of its own (envs/sensor.py), so varying any sensor option leaves the pushes,
throws, occluders and target motion of episode i as they were, except an option that is
also part of the world's dynamics: BallTable's and TargetFollower's ``frame_rate_hz`` is
their control rate (``world_shaping_sensor_options`` of the env class).
"""

from __future__ import annotations

import argparse
import dataclasses
import difflib
import itertools
import json
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from observer_gym.envs import System, system_for_id
from observer_gym.train.core.args import point_text, value_text

# A sweep's keys and values: {key: values} or [(key, values), ...] (the command line's
# --vary, where a key may repeat, which is refused).
VaryInput = Mapping[str, Sequence[Any]] | Sequence[tuple[str, Sequence[Any]]]

_TRUE = ("true", "yes", "1")
_FALSE = ("false", "no", "0")


@dataclass(frozen=True)
class Grid:
    """The keys that vary (in the order given) and each key's distinct values, in the
    types of the env's configuration."""

    keys: tuple[str, ...]
    values: tuple[tuple[Any, ...], ...]

    def points(self) -> list[dict[str, Any]]:
        """Every grid point as {key: value}, the first key outermost."""
        return [
            dict(zip(self.keys, combo, strict=True)) for combo in itertools.product(*self.values)
        ]

    def as_dict(self) -> dict[str, list[Any]]:
        """{key: [values]} in the keys' order."""
        return {key: list(values) for key, values in zip(self.keys, self.values, strict=True)}

    def first(self) -> dict[str, Any]:
        """The first grid point: every key at its first value."""
        return {key: values[0] for key, values in zip(self.keys, self.values, strict=True)}


def vary_option(text: str) -> tuple[str, list[str]]:
    """argparse type: ``KEY=V1,V2,...`` -> (KEY, [V1, V2, ...]) with the values as text;
    an empty key, no value or an empty value is refused."""
    key, sep, values = text.partition("=")
    key = key.strip()
    if not sep or not key.isidentifier():
        raise argparse.ArgumentTypeError(f"expected KEY=V1,V2,..., got {text!r}")
    items = [item.strip() for item in values.split(",")]
    if items == [""]:
        raise argparse.ArgumentTypeError(f"{key} has an empty value list: write {key}=V1,V2,...")
    if "" in items:
        raise argparse.ArgumentTypeError(f"{key} has an empty value in {values!r}")
    return key, items


def _allowed(field: dataclasses.Field) -> str:
    """What a field takes, as its configuration's messages say it."""
    meta = field.metadata
    if meta.get("choices") is not None:
        return f"choose one of {list(meta['choices'])}"
    if meta.get("low") is not None or meta.get("high") is not None:
        return f"allowed: [{meta['low']}, {meta['high']}]"
    return f"a {type(field.default).__name__}"


def parse_value(field: dataclasses.Field, value: Any) -> Any:
    """``value`` in the type of the configuration ``field``: text is read as the field's
    default's type (bool: true/false/yes/no/1/0, int, float; text stays text); other
    values are kept for the configuration to check. ValueError naming the field, the
    value and what it takes."""
    if not isinstance(value, str):
        return value
    default, text = field.default, value.strip()
    if isinstance(default, bool):
        if text.lower() in _TRUE + _FALSE:
            return text.lower() in _TRUE
        raise ValueError(f"{field.name}={text!r} is not true or false")
    if isinstance(default, int) and field.metadata.get("choices") is None:
        try:
            return int(text)
        except ValueError:
            raise ValueError(
                f"{field.name}={text!r} is not an integer; {_allowed(field)}"
            ) from None
    if isinstance(default, float):
        try:
            return float(text)
        except ValueError:
            raise ValueError(f"{field.name}={text!r} is not a number; {_allowed(field)}") from None
    return text


def _pairs(vary: VaryInput) -> list[tuple[str, list[Any]]]:
    """``vary`` as (key, values) pairs; ValueError for a repeated key or no key."""
    pairs = list(vary.items()) if isinstance(vary, Mapping) else [tuple(p) for p in vary]
    if not pairs:
        raise ValueError("vary must name at least one env option (KEY=V1,V2,...)")
    keys = [str(key) for key, _ in pairs]
    repeated = sorted({key for key in keys if keys.count(key) > 1})
    if repeated:
        raise ValueError(f"vary names {', '.join(repeated)} more than once")
    result = []
    for key, values in pairs:
        if isinstance(values, str):
            values = values.split(",")
        result.append((str(key), list(values)))
    return result


def check_grid(
    env_id: str | System,
    vary: VaryInput,
    env_kwargs: Mapping[str, Any] | None = None,
    obs_modes: Iterable[str] = ("state",),
) -> Grid:
    """The grid of ``vary`` for ``env_id`` (an id, or the system resolved once by the
    caller), its values in the configuration's types.

    Checks, in this order, naming what is allowed: every key is a field of the env's
    configuration (not ``obs_mode``, not one ``env_kwargs`` sets, none twice); every key
    has at least one value, each read as the field's type (:func:`parse_value`), in its
    range, and none twice; then the configuration of every grid point with
    ``env_kwargs`` builds with every obs_mode of ``obs_modes`` (checks between options,
    e.g. a frame phase within the frame period).

    Raises:
        ValueError: one line naming the key, the value and what is allowed.
    """
    system = env_id if isinstance(env_id, System) else system_for_id(env_id)
    config_class = system.env_class().config_class
    fields = {f.name: f for f in dataclasses.fields(config_class) if f.init}
    allowed = [name for name in fields if name != "obs_mode"]
    env_kwargs = dict(env_kwargs or {})
    obs_modes = list(dict.fromkeys(obs_modes)) or ["state"]
    keys, values = [], []
    for key, raw in _pairs(vary):
        if key == "obs_mode":
            raise ValueError("vary: obs_mode cannot vary: each observer decides it")
        if key not in fields:
            close = difflib.get_close_matches(key, allowed, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise ValueError(
                f"vary: {system.short_id} has no option {key!r}{hint}; allowed: "
                + ", ".join(allowed)
            )
        if key in env_kwargs:
            raise ValueError(f"vary: {key} is also set as an env option; give it in one place")
        if not raw:
            raise ValueError(f"vary {key}: no values given (write {key}=V1,V2,...)")
        typed = []
        for value in raw:
            try:
                parsed = parse_value(fields[key], value)
                config = config_class.from_kwargs(**{**env_kwargs, key: parsed})
            except (TypeError, ValueError) as exc:
                raise ValueError(f"vary {key}: {exc}") from None
            typed.append(getattr(config, key))  # the configuration's type (0 -> 0.0)
        seen = [json.dumps(v) for v in typed]
        repeated = sorted(
            {value_text(v) for v, s in zip(typed, seen, strict=True) if seen.count(s) > 1}
        )
        if repeated:
            raise ValueError(f"vary {key}: the value {', '.join(repeated)} appears more than once")
        keys.append(key)
        values.append(tuple(typed))
    grid = Grid(tuple(keys), tuple(values))
    for point in grid.points():
        for obs_mode in obs_modes:
            try:
                config_class.from_kwargs(**{**env_kwargs, **point, "obs_mode": obs_mode})
            except (TypeError, ValueError) as exc:
                raise ValueError(
                    f"vary: the grid point {point_text(point)} is not a valid "
                    f"{system.short_id} configuration: {exc}"
                ) from None
    return grid


def world_draw_notes(env_id: str | System, grid: Grid) -> list[str]:
    """One sentence per varied key of ``grid`` that is a sensor option and also part of
    the world's dynamics (the env class's ``world_shaping_sensor_options``, e.g. a frame
    rate that is the control rate), so that episode i meets another world at each value."""
    system = env_id if isinstance(env_id, System) else system_for_id(env_id)
    env_class = system.env_class()
    shaping = getattr(env_class, "world_shaping_sensor_options", ())
    return [
        f"varying {key} changes the world's steps too ({key} is also {env_class.__name__}'s "
        f"control rate): episode i meets other disturbances at different {key} values "
        "(docs/sweep.md)"
        for key, values in zip(grid.keys, grid.values, strict=True)
        if key in shaping and len(values) > 1
    ]
