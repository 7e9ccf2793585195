"""Domain randomisation of the env's options while training (``observer-gym train
--randomize KEY=LOW:HIGH``, ``KEY=A|B``).

A randomisation maps ``gym.make`` options to what each training episode draws for them:

- ``{"low": LOW, "high": HIGH}``: a number uniform in [LOW, HIGH] (an integer option: an
  integer uniform in LOW..HIGH, both included);
- ``{"choices": [A, B, ...]}``: one of the values, each equally likely (for options that
  are no numbers: ``camera_preset``, ``air_drag``).

:class:`RandomizedEnv` is the training env of a randomised run: at each reset it draws the
options, closes the world it holds and builds a new one (the env and its observer stack,
exactly as training builds it for fixed options, with the drawn options over the fixed
ones): only a rebuilt world equals a fresh one. Its draws come from a generator seeded at
``reset(seed=s)`` with ``s``, which training derives from the run's seed and the env's rank
(:mod:`observer_gym.train.rl.learning`), so a run repeats with its seed; each episode draws
its options first, then the new world's seed.

Only training randomises: a run records its randomisation in config.json (``randomize``)
beside its fixed ``env_kwargs``, ``--resume`` continues it, and ``evaluate``, ``run``,
``compare`` and ``benchmark`` (and the run's own evaluation curve) load the agent on the
fixed options.

This module imports no PyTorch and builds no world to check a randomisation
(:func:`check_randomize`: the env's configuration class at every corner of the box the
draws fill, every combination of the ranges' ends and the choices). The corners cover
every draw because every rule the configurations check between options is monotone in
each option (a bound on one option, on a sum, difference or product of options, a
shortest below a longest): it holds over the whole box if it holds at its corners. The one
rule that is not, a whole multiple (BallCatcher's ``control_dt_s`` of ``physics_dt_s``,
named by the configuration's ``discrete_options``), is refused as a range of width above
zero (almost every draw of it fails): draw such an option from choices. Above
:data:`MAX_CORNERS` corners a randomisation is refused. Training also builds the agent's
env once per choice and range end (:func:`check_spaces`), since :class:`RandomizedEnv`
needs every draw to keep its spaces (a camera count, for pixels).
"""

from __future__ import annotations

import ast
import dataclasses
import itertools
import math
from collections.abc import Callable, Mapping
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np

# gym.make keywords that no randomisation may draw
NOT_RANDOMIZED = ("obs_mode", "render_mode", "max_episode_steps", "disable_env_checker")
FORMS = "KEY=LOW:HIGH (a number uniform in [LOW, HIGH]) or KEY=A|B|... (one of the values)"
# the most corners (combinations of the ranges' ends and the choices) a check builds
MAX_CORNERS = 4096


def _literal(text: str) -> Any:
    """``text`` read as a Python literal (``True``, ``2``, ``'a'``), else kept as text."""
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return text


def _is_number(value: Any) -> bool:
    return (
        isinstance(value, int | float)
        and not isinstance(value, bool)
        and math.isfinite(float(value))
    )


def parse_randomize_text(text: str) -> tuple[str, dict[str, Any]]:
    """``KEY=LOW:HIGH`` or ``KEY=A|B|...`` read as ``(KEY, spec)`` (see the module
    docstring); a choice's values are read as Python literals (``True``, ``2``), else kept
    as text. ValueError naming what is wrong and the forms allowed."""
    key, sep, value = text.partition("=")
    if not sep or not key.isidentifier():
        raise ValueError(f"expected {FORMS}, got {text!r}")
    if "|" in value:
        choices = [_literal(part.strip()) for part in value.split("|")]
        if any(part.strip() == "" for part in value.split("|")):
            raise ValueError(f"{key}: an empty choice in {value!r}; expected {FORMS}")
        return key, _checked_spec(key, {"choices": choices})
    low_text, sep, high_text = value.partition(":")
    if not sep:
        raise ValueError(f"{key}: expected LOW:HIGH or A|B|..., got {value!r} ({FORMS})")
    try:
        low, high = float(low_text), float(high_text)
    except ValueError:
        raise ValueError(f"{key}: LOW and HIGH must be numbers, got {value!r}") from None
    # an integer written as one stays an integer (for integer options)
    bounds = [
        int(number) if part.strip().lstrip("+-").isdigit() else number
        for part, number in ((low_text, low), (high_text, high))
    ]
    return key, _checked_spec(key, {"low": bounds[0], "high": bounds[1]})


def _checked_spec(key: str, spec: Any) -> dict[str, Any]:
    """``spec`` as a plain dict, or ValueError naming ``key`` and what is allowed."""
    if not isinstance(spec, Mapping):
        raise ValueError(
            f"randomize {key}: expected {{'low': LOW, 'high': HIGH}} or "
            f"{{'choices': [...]}}, got {spec!r}"
        )
    if set(spec) == {"low", "high"}:
        low, high = spec["low"], spec["high"]
        if not (_is_number(low) and _is_number(high)):
            raise ValueError(f"randomize {key}: LOW and HIGH must be finite numbers, got {spec!r}")
        if low > high:
            raise ValueError(f"randomize {key}: LOW={low} is above HIGH={high}; need LOW <= HIGH")
        return {"low": low, "high": high}
    if set(spec) == {"choices"}:
        choices = list(spec["choices"]) if isinstance(spec["choices"], list | tuple) else None
        if not choices:
            raise ValueError(f"randomize {key}: choices must be a non-empty list, got {spec!r}")
        if any(not isinstance(c, str | int | float | bool) for c in choices):
            raise ValueError(
                f"randomize {key}: choices must be numbers, text or True/False, got {choices!r}"
            )
        if len({(type(c), c) for c in choices}) != len(choices):
            raise ValueError(f"randomize {key}: a choice is listed twice in {choices!r}")
        return {"choices": choices}
    raise ValueError(
        f"randomize {key}: expected {{'low': LOW, 'high': HIGH}} or {{'choices': [...]}}, "
        f"got {dict(spec)!r}"
    )


def check_randomize(
    env_id: str,
    obs_mode: str,
    env_kwargs: Mapping[str, Any],
    randomize: Mapping[str, Any] | None,
    fixed: Mapping[str, Any] | None = None,
    fixed_by: str = "env_kwargs",
) -> dict[str, dict[str, Any]]:
    """``randomize`` checked against ``env_id``'s options, as a plain dict.

    Every key must be an option of the env's configuration class (not ``obs_mode`` or a
    ``gym.make`` keyword), none of ``fixed`` (the options given as fixed ones, named
    ``fixed_by`` in the message), and the env must take every end of a range and every
    choice with the others at ``env_kwargs`` (the run's fixed options), and every
    combination of them (the box's corners: then every draw, see the module docstring;
    at most :data:`MAX_CORNERS`). A range of an integer option must have integer ends; an
    option of the configuration's ``discrete_options`` takes no range wider than zero.
    Imports the env's module; builds no world.

    Raises:
        ValueError: naming the key, what was wrong and what is allowed.
    """
    from observer_gym.envs import system_for_id

    if not randomize:
        return {}
    system = system_for_id(env_id)
    config_class = system.env_class().config_class
    fields = {f.name: f for f in dataclasses.fields(config_class)}
    checked: dict[str, dict[str, Any]] = {}
    for key, spec in randomize.items():
        if key in NOT_RANDOMIZED:
            raise ValueError(f"randomize {key}: not an option a training episode can draw")
        if key not in fields:
            allowed = ", ".join(k for k in fields if k not in NOT_RANDOMIZED)
            raise ValueError(
                f"randomize {key}: {system.short_id} has no option {key!r}; allowed: {allowed}"
            )
        if fixed and key in fixed:
            raise ValueError(
                f"randomize {key}: also given as a fixed option ({fixed_by}); give it one way"
            )
        spec = _checked_spec(key, spec)
        default = fields[key].default
        if "low" in spec:
            if isinstance(default, bool) or not isinstance(default, int | float):
                raise ValueError(
                    f"randomize {key}: {system.short_id}'s {key} is no number "
                    f"(default {default!r}); draw it from choices: {key}=A|B"
                )
            if isinstance(default, int) and not all(isinstance(spec[e], int) for e in spec):
                raise ValueError(
                    f"randomize {key}: {key} is an integer option; LOW and HIGH must be "
                    f"integers, got {spec['low']}:{spec['high']}"
                )
            discrete = getattr(config_class, "discrete_options", {})
            if key in discrete and spec["low"] != spec["high"]:
                raise ValueError(
                    f"randomize {key}: {key} must be {discrete[key]}, which almost no value "
                    f"between {spec['low']} and {spec['high']} is, so a draw would fail; "
                    f"draw it from choices: {key}=A|B"
                )
        checked[key] = spec
    base = {k: v for k, v in env_kwargs.items() if k not in NOT_RANDOMIZED}

    def build(options: Mapping[str, Any], what: str) -> None:
        try:
            config_class.from_kwargs(obs_mode=obs_mode, **{**base, **options})
        except ValueError as exc:
            raise ValueError(
                f"randomize {what}: {system.short_id} refuses it: {' '.join(str(exc).split())}"
            ) from None

    # the box's corners: each range at either end, each choice (a randomised option's
    # default never applies, so none is checked with the others at theirs)
    values = [
        spec["choices"] if "choices" in spec else list(dict.fromkeys([spec["low"], spec["high"]]))
        for spec in checked.values()
    ]
    corners = math.prod(len(v) for v in values)
    if corners > MAX_CORNERS:
        raise ValueError(
            f"randomize: {corners} combinations of the ranges' ends and the choices to "
            f"check, at most {MAX_CORNERS} allowed; randomise fewer options or choices"
        )
    for corner in itertools.product(*values):
        options = dict(zip(checked, corner, strict=True))
        named = ", ".join(f"{k}={v!r}" for k, v in options.items())
        build(options, named if len(options) == 1 else f"with {named} together")
    return checked


def check_spaces(
    make_inner: Callable[[Mapping[str, Any]], gym.Env],
    randomize: Mapping[str, Mapping[str, Any]],
) -> None:
    """ValueError naming the option unless every choice and range end of ``randomize``
    (a checked randomisation) gives the agent's env the spaces it has with every option
    at its first value (each varied alone), as :class:`RandomizedEnv` requires of every
    draw. Builds one world per value (``make_inner``: the agent's env for the options it
    is given over the run's fixed ones); an option whose values differ only in number
    cannot change the spaces between its ends (image sizes and camera counts are
    integers, each end a value a draw takes)."""
    first = {k: s["choices"][0] if "choices" in s else s["low"] for k, s in randomize.items()}

    def spaces_of(options: Mapping[str, Any]) -> tuple[Any, Any]:
        env = make_inner(options)
        try:
            return env.observation_space, env.action_space
        finally:
            env.close()

    expected = spaces_of(first)
    for key, spec in randomize.items():
        others = spec["choices"][1:] if "choices" in spec else [spec["high"]]
        for value in others:
            if value == first[key]:
                continue
            found = spaces_of({**first, key: value})
            if found != expected:
                raise ValueError(
                    f"randomize {key}: {key}={value!r} changes the agent's spaces "
                    f"({found[0]} / {found[1]}; with {key}={first[key]!r}: {expected[0]} / "
                    f"{expected[1]}); randomise only options that keep them, or fix {key}"
                )


def draw_options(
    randomize: Mapping[str, Mapping[str, Any]],
    rng: np.random.Generator,
    integer_keys: frozenset[str] = frozenset(),
) -> dict[str, Any]:
    """One episode's options: each key of ``randomize`` drawn with ``rng``, in the
    randomisation's order (a number uniform in [low, high], an integer option's integer
    uniform in low..high, or one of the choices)."""
    drawn: dict[str, Any] = {}
    for key, spec in randomize.items():
        if "choices" in spec:
            drawn[key] = spec["choices"][int(rng.integers(len(spec["choices"])))]
        elif key in integer_keys:
            drawn[key] = int(rng.integers(int(spec["low"]), int(spec["high"]) + 1))
        else:
            drawn[key] = float(rng.uniform(float(spec["low"]), float(spec["high"])))
    return drawn


def randomize_of_ranges(ranges: Mapping[str, tuple[Any, ...]]) -> dict[str, dict[str, Any]]:
    """A declared table of ranges (a learned observer's ``TRAINING_RANGES``: ``(LOW, HIGH)``
    numbers, or a tuple of text values to choose from) as a randomisation for
    :func:`draw_options`: the same draws from the same generator."""
    randomize: dict[str, dict[str, Any]] = {}
    for key, values in ranges.items():
        if values and all(isinstance(v, str) for v in values):
            randomize[key] = _checked_spec(key, {"choices": list(values)})
        elif len(values) == 2:
            randomize[key] = _checked_spec(key, {"low": values[0], "high": values[1]})
        else:
            raise ValueError(
                f"randomize {key}: expected (LOW, HIGH) or a tuple of text choices, got {values!r}"
            )
    return randomize


def space_structure(space: gym.Space) -> Any:
    """What of ``space`` a draw must keep when bounds may differ: its type, and a Box's
    shape and dtype (a Dict's and a Tuple's per entry; any other space whole)."""
    if isinstance(space, gym.spaces.Box):
        return ("Box", space.shape, space.dtype)
    if isinstance(space, gym.spaces.Dict):
        return ("Dict", tuple((k, space_structure(v)) for k, v in space.spaces.items()))
    if isinstance(space, gym.spaces.Tuple):
        return ("Tuple", tuple(space_structure(v) for v in space.spaces))
    return space


def union_space(spaces: list[gym.Space]) -> gym.Space:
    """The smallest space holding every one of ``spaces`` (of one
    :func:`space_structure`): a Box's low the least of theirs, its high the greatest; a
    Dict's and a Tuple's per entry; any other space must be equal in all. ValueError if
    their structures differ."""
    first = spaces[0]
    if any(space_structure(s) != space_structure(first) for s in spaces):
        raise ValueError(f"spaces of different structure cannot be joined: {spaces}")
    if isinstance(first, gym.spaces.Box):
        low = np.min([np.asarray(s.low) for s in spaces], axis=0)  # type: ignore[attr-defined]
        high = np.max([np.asarray(s.high) for s in spaces], axis=0)  # type: ignore[attr-defined]
        return gym.spaces.Box(low, high, first.shape, first.dtype)
    if isinstance(first, gym.spaces.Dict):
        return gym.spaces.Dict(
            {k: union_space([s[k] for s in spaces]) for k in first.spaces}  # type: ignore[index]
        )
    if isinstance(first, gym.spaces.Tuple):
        return gym.spaces.Tuple(
            [union_space([s[i] for s in spaces]) for i in range(len(first.spaces))]  # type: ignore[index]
        )
    return first  # a space without bounds: equal in all (its structure is itself)


def end_values(randomize: Mapping[str, Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Every choice and range end of ``randomize``, each varied alone with the others at
    their first value (as :func:`check_spaces` builds them), the first values first."""
    first = {k: s["choices"][0] if "choices" in s else s["low"] for k, s in randomize.items()}
    ends = [first]
    for key, spec in randomize.items():
        for value in spec["choices"][1:] if "choices" in spec else [spec["high"]]:
            if value != first[key]:
                ends.append({**first, key: value})
    return ends


def integer_options(env_id: str) -> frozenset[str]:
    """The options of ``env_id`` that are integers (drawn as integers)."""
    from observer_gym.envs import system_for_id

    config_class = system_for_id(env_id).env_class().config_class
    return frozenset(
        f.name
        for f in dataclasses.fields(config_class)
        if isinstance(f.default, int) and not isinstance(f.default, bool)
    )


class RandomizedEnv(gym.Env):
    """A training env whose options are drawn anew at every reset (module docstring).

    Args:
        make_inner: builds the inner env (the env, its observer stack and the agent's
            wrappers) for the options it is given, over the run's fixed ones.
        env_id: the env, whose integer options are drawn as integers.
        randomize: the checked randomisation (:func:`check_randomize`).
        world_seeds_below: each world's seed is drawn uniform in 0..this - 1.
        bounds_may_differ: a draw may change the bounds of a space, not its structure
            (types, shapes, dtypes: :func:`space_structure`); for a recording, whose
            observation space is the union of the draws' (:func:`union_space`), not for
            an agent, which reads the bounds.
        integers: draw the env's integer options as integers (else every range's draw
            is a float, as the learned observers' collections draw theirs).

    Attributes:
        inner: the world of the current episode.
        options: the options drawn for it.
        world_seed: the seed its reset was given (None before the first reset).
        episodes: how many worlds this env has built.
    """

    def __init__(
        self,
        make_inner: Callable[[Mapping[str, Any]], gym.Env],
        env_id: str,
        randomize: Mapping[str, Mapping[str, Any]],
        world_seeds_below: int = 2**31 - 1,
        integers: bool = True,
        bounds_may_differ: bool = False,
    ) -> None:
        self._same = space_structure if bounds_may_differ else (lambda space: space)
        self._make_inner = make_inner
        self.randomize = {k: dict(v) for k, v in randomize.items()}
        self._integers = integer_options(env_id) if integers else frozenset()
        self._world_seeds_below = int(world_seeds_below)
        self.world_seed: int | None = None
        # until the first reset(seed=...); training seeds every env's first reset
        self._rng = np.random.default_rng(0)
        self.options = draw_options(self.randomize, np.random.default_rng(0), self._integers)
        self.inner: gym.Env | None = make_inner(self.options)
        self.episodes = 1
        self._first = True  # the world built here has not run an episode yet
        self.observation_space = self.inner.observation_space
        self.action_space = self.inner.action_space
        self.metadata = dict(self.inner.metadata)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        drawn = draw_options(self.randomize, self._rng, self._integers)
        world_seed = int(self._rng.integers(self._world_seeds_below))
        if not (self._first and drawn == self.options):
            self._rebuild(drawn)
        self._first = False
        assert self.inner is not None  # built above or at construction
        self.world_seed = world_seed
        observation, info = self.inner.reset(seed=world_seed, options=options)
        return observation, {**info, "randomized": dict(self.options)}

    def _rebuild(self, drawn: dict[str, Any]) -> None:
        if self.inner is not None:
            self.inner.close()
            self.inner = None
        inner = self._make_inner(drawn)
        if self._same(inner.observation_space) != self._same(self.observation_space) or self._same(
            inner.action_space
        ) != self._same(self.action_space):
            inner.close()
            raise ValueError(
                f"randomized options {drawn} change the env's spaces "
                f"({inner.observation_space} / {inner.action_space}, first "
                f"{self.observation_space} / {self.action_space}); randomise only options "
                "that keep them"
            )
        self.inner, self.options = inner, drawn
        self.episodes += 1

    @property
    def rng(self) -> np.random.Generator:
        """The generator of the draws (seeded at ``reset(seed=...)``), for a player that
        draws from the same stream between resets (a learned observer's action noise)."""
        return self._rng

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        assert self.inner is not None, "reset the env first"
        return self.inner.step(action)

    def render(self) -> Any:
        return None if self.inner is None else self.inner.render()

    def close(self) -> None:
        if self.inner is not None:
            self.inner.close()
            self.inner = None
