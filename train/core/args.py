"""The parser and argparse types of every command line of ``observer_gym.train`` (the
``observer-gym`` subcommands, the reproductions, the consistency study, the leaderboard,
the encoder's pretraining): a mistake is answered with one line on stderr,
``PROG: error: MESSAGE`` (:func:`error_line`, :class:`Parser`), exit code 2.

Parsing imports nothing heavy: env ids come from the system registry
(:data:`observer_gym.envs.SYSTEMS`, which imports Gymnasium only). The options only the
``observer-gym`` command takes are :mod:`observer_gym.train.cli.args`.
"""

from __future__ import annotations

import argparse
import ast
import functools
import math
import sys
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, NoReturn

from observer_gym.train.core.messages import UsageError, error_line

# Placeholders in help texts for the installed packages' entry points, filled in only
# when --help is shown (reading the installed packages takes ~0.1 s).
INSTALLED = {"observer": "<installed observers>", "controller": "<installed controllers>"}
# and for every system's observers and controllers, read from the layers (~1.5 s)
PER_ENV = {"observers": "<observers per env>", "controllers": "<controllers per env>"}


class HelpFormatter(argparse.HelpFormatter):
    """argparse's help formatter, with :data:`INSTALLED`'s placeholders replaced by the
    names of the installed entry points
    (:func:`observer_gym.train.core.entries.entry_points`) and :data:`PER_ENV`'s by
    every system's observers or controllers."""

    def _expand_help(self, action: argparse.Action) -> str:
        text = super()._expand_help(action)
        for kind, marker in INSTALLED.items():
            if marker in text:
                from observer_gym.train.core.entries import entry_points

                names = ", ".join(sorted(entry_points(kind))) or "none"
                text = text.replace(marker, f"installed: {names}")
        for field, marker in PER_ENV.items():
            if marker in text:
                from observer_gym.train.core.systems import per_env

                text = text.replace(marker, per_env(field))
        return text


class Parser(argparse.ArgumentParser):
    """argparse's parser whose mistakes are one line on stderr, ``PROG: error: MESSAGE``
    (with a pointer to ``--help`` instead of the usage), raising :class:`UsageError`
    (exit code 2). Its subparsers are of this class too, and all format their help with
    :class:`HelpFormatter`."""

    def __init__(self, *args, **kwargs) -> None:
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> NoReturn:
        line = error_line(self.prog, f"{message} (see '{self.prog} --help')")
        print(line, file=sys.stderr)
        raise UsageError(line)


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text}")
    return value


def _int_at_least(minimum: int, text: str) -> int:
    """An integer >= ``minimum`` parsed from ``text``, or argparse's type error."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value < minimum:
        raise argparse.ArgumentTypeError(f"must be an integer >= {minimum}, got {text}")
    return value


def int_at_least(minimum: int) -> Callable[[str], int]:
    """argparse type: an integer >= ``minimum``."""
    return functools.partial(_int_at_least, minimum)


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    return _int_at_least(1, text)


def nonnegative_int(text: str) -> int:
    """argparse type: an integer >= 0."""
    return _int_at_least(0, text)


def seed_list(text: str) -> list[int]:
    """argparse type: comma-separated seeds >= 0 and ranges ``A-B`` (both ends included):
    ``0-4,10,12-13`` -> [0, 1, 2, 3, 4, 10, 12, 13]."""
    seeds: list[int] = []
    for part in text.split(","):
        first, sep, last = part.strip().partition("-")
        if sep and not first:  # "-1"
            raise argparse.ArgumentTypeError(
                f"{part.strip()!r} in {text!r}: seeds must be integers >= 0"
            )
        try:
            low = int(first)
            high = int(last) if sep else low
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{part.strip()!r} in {text!r} is not a seed or a range A-B of seeds >= 0"
            ) from None
        if low < 0 or high < low:
            raise argparse.ArgumentTypeError(
                f"{part.strip()!r} in {text!r}: seeds must be >= 0 and a range A-B needs A <= B"
            )
        seeds += range(low, high + 1)
    return seeds


def distinct_seeds(text: str) -> list[int]:
    """argparse type: :func:`seed_list` with every seed once (``0,1,2``, ``0-4``)."""
    seeds = seed_list(text)
    repeated = sorted({seed for seed in seeds if seeds.count(seed) > 1})
    if repeated:
        raise argparse.ArgumentTypeError(
            f"{text!r} lists seed(s) {', '.join(map(str, repeated))} more than once; "
            "each seed trains one agent"
        )
    return seeds


def folder_path(text: str) -> Path:
    """argparse type: a folder's path; an empty one (which would mean the current
    folder) is refused."""
    if not text.strip():
        raise argparse.ArgumentTypeError(
            "expected a folder, got an empty path (write '.' for the current folder)"
        )
    return Path(text)


def env_name(text: str) -> str:
    """argparse type: a registered env id, with or without its ``observer_gym/`` prefix."""
    from observer_gym.envs import system_for_id  # deferred: registers the envs

    try:
        return system_for_id(text).env_id
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def literal(value: str) -> object:
    """``value`` read as a Python literal (number, True, 'text'), else kept as text."""
    try:
        return ast.literal_eval(value)
    except (ValueError, SyntaxError):
        return value


def value_text(value: Any) -> str:
    """A value as the command line writes it back (``0.02``, ``True``, ``single``), what
    :func:`literal` reads back."""
    return value if isinstance(value, str) else repr(value)


def point_text(point: Mapping[str, Any]) -> str:
    """Options (a sweep's grid point) as ``key=value, key=value``."""
    return ", ".join(f"{key}={value_text(value)}" for key, value in point.items())


def env_option(text: str) -> tuple[str, object]:
    """argparse type: ``KEY=VALUE``, the value read as a Python literal (number, True,
    'text') or else kept as text: ``camera_preset=single``, ``latency_s=0.02``."""
    key, sep, value = text.partition("=")
    if not sep or not key.isidentifier():
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    return key, literal(value)


def add_env_option_argument(parser: argparse.ArgumentParser, help_text: str) -> None:
    """``--env-option KEY=VALUE`` (repeatable, :func:`env_option`) with ``help_text``."""
    parser.add_argument(
        "--env-option",
        type=env_option,
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help=help_text,
    )
