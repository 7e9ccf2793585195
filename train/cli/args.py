"""The parser, argparse types and shared options of the ``observer-gym`` subcommands.

Parsing imports nothing heavy: env ids come from the system registry
(:data:`observer_gym.envs.SYSTEMS`, which imports Gymnasium only) and controller names
from :mod:`observer_gym.train.core.checks`. A mistake is answered with one line on stderr
(:class:`Parser`).
"""

from __future__ import annotations

import argparse
import ast
import functools
import math
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple, NoReturn

from observer_gym.train.core.checks import ALGOS


class UsageError(SystemExit):
    """A mistake in the command line: exit code 2; ``str()`` is the message."""

    def __init__(self, message: str) -> None:
        super().__init__(2)
        self.message = message

    def __str__(self) -> str:
        return self.message


def one_line(text: object) -> str:
    """``text`` with every run of whitespace (newlines too) made one space."""
    return " ".join(str(text).split())


def error_line(prog: str, message: object) -> str:
    """The one line that reports a mistake: ``PROG: error: MESSAGE``."""
    return f"{prog}: error: {one_line(message)}"


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


def add_output_arguments(parser: argparse.ArgumentParser, command: str) -> None:
    """``--out DIR`` (default ``default_out_dir(command)``'s pattern; not empty) and
    ``--no-progress``, the two options every command that writes results takes."""
    parser.add_argument(
        "--out",
        type=folder_path,
        default=None,
        metavar="DIR",
        help=(
            f"output folder (default: ./observer-gym-out/{command}-YYYYmmdd-HHMMSS-PID); one "
            "command at a time: while another command writes there, this one is refused "
            "(exit code 75)"
        ),
    )
    parser.add_argument("--no-progress", action="store_true", help="do not show the progress bar")


class Progress(NamedTuple):
    """How a long command shows its progress (:func:`progress_display`)."""

    bar: bool  # a bar over the episodes (a terminal)
    lines: Callable[[str], None] | None  # prints one line per finished part (no terminal)


def progress_display(prog: str, no_progress: bool) -> Progress:
    """On a terminal (stderr) a bar; off one, one line on stderr per finished part (a
    sweep's cell, a benchmark's level: ``PROG: cell 2/6 finished: ...``), as the library
    reports them; with ``--no-progress`` neither."""
    if no_progress:
        return Progress(False, None)
    if sys.stderr.isatty():
        return Progress(True, None)

    def lines(line: str) -> None:
        print(f"{prog}: {line}", file=sys.stderr, flush=True)

    return Progress(False, lines)


def add_backend_arguments(parser: argparse.ArgumentParser) -> None:
    """``--workers W``, ``--backend {local,ray}`` and ``--address ADDR``: where the episodes
    of ``compare``, ``sweep`` and ``benchmark`` run (the results do not depend on it)."""
    parser.add_argument(
        "--workers",
        type=positive_int,
        default=1,
        metavar="W",
        help="local backend: run episodes in W processes; results are identical (default: 1)",
    )
    parser.add_argument(
        "--backend",
        choices=("local", "ray"),
        default="local",
        help=(
            "local: this machine's processes; ray: Ray tasks, same results "
            "(pip install 'observer-gym[distributed]') (default: %(default)s)"
        ),
    )
    parser.add_argument(
        "--address",
        default=None,
        metavar="ADDR",
        help=(
            "with --backend ray: the Ray cluster to use ('auto' for the one 'ray start' set "
            "up here, or HOST:PORT) (default: start a local Ray instance)"
        ),
    )


def controller_name(text: str) -> str:
    """argparse type: a controller of some system, a trained agent ``ALGO:DIR``, a
    stable-baselines3 zip ``ALGO:PATH.zip`` or an outside controller (an import path or an
    installed entry point's name); whether it fits the env is checked with the env."""
    from observer_gym.train.core.entries import find_plugin
    from observer_gym.train.core.systems import controller_choices

    controllers = controller_choices()
    algo, sep, run_dir = text.partition(":")
    if text in controllers or (sep and algo in ALGOS and run_dir):
        return text
    if find_plugin("controller", text) is not None:
        return text
    raise argparse.ArgumentTypeError(
        f"{text!r} is neither a controller ({', '.join(controllers)}), a trained agent "
        f"ALGO:DIR or ALGO:PATH.zip with ALGO one of {', '.join(ALGOS)}, nor an import path "
        "package.module:factory or an installed entry point"
    )


def entry_option(text: str) -> tuple[str, object]:
    """argparse type: ``KEY=VALUE`` of an observer's or controller's options, the value
    read as :func:`env_option` reads it."""
    return env_option(text)


def add_entry_option_arguments(parser: argparse.ArgumentParser) -> None:
    """``--observer-option`` and ``--controller-option KEY=VALUE`` (repeatable): keyword
    arguments of every observer's pipeline (or outside factory) and every controller's
    design (or outside factory) of the command."""
    for kind, example in (("observer", "alpha=0.5"), ("controller", "gain=0.8")):
        parser.add_argument(
            f"--{kind}-option",
            type=entry_option,
            action="append",
            default=[],
            metavar="KEY=VALUE",
            help=f"a keyword argument of every {kind}'s factory, repeatable (e.g. {example}); "
            f"recorded in results.json",
        )


# What else an observer or a controller can be, for --help.
OUTSIDE_OBSERVERS_HELP = (
    "or an outside observer: an import path package.module:factory, or an installed "
    f"entry point of the group observer_gym.observers ({INSTALLED['observer']}), each "
    "reading camera frames, or measurements with the suffix -measurements"
)
OUTSIDE_CONTROLLERS_HELP = (
    "a stable-baselines3 zip as ALGO:PATH.zip (load only trusted files: it is unpickled); "
    "or an outside controller: an import path package.module:factory or an installed "
    f"entry point of the group observer_gym.controllers ({INSTALLED['controller']})"
)

# What a command that loads trained agents or outside entries runs, for its --help.
TRUST_HELP = (
    " Trust: a trained agent (ALGO:DIR, ALGO:PATH.zip) holds a stable-baselines3 zip, "
    "which loading partly unpickles, and an outside observer or controller is code that is "
    "imported and run: use them only from a source you trust. An agent folder is refused if "
    "its files differ from the sha256 the run recorded; its VecNormalize statistics are read "
    "as plain arrays, never unpickled (docs/trust.md)."
)


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


def randomize_option(text: str) -> tuple[str, dict[str, object]]:
    """argparse type: ``KEY=LOW:HIGH`` (numbers, LOW <= HIGH) or ``KEY=A|B|...`` (values
    read as Python literals, else text) of ``train --randomize``
    (:func:`observer_gym.train.rl.randomize.parse_randomize_text`)."""
    from observer_gym.train.rl.randomize import parse_randomize_text  # gymnasium, numpy

    try:
        return parse_randomize_text(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def hyperparam_option(text: str) -> tuple[str, object]:
    """argparse type: ``KEY=VALUE`` with a dotted key for nested values
    (``learning_rate=1e-4``, ``normalize.norm_reward=False``); the value is read as a
    Python literal, else kept as text."""
    key, sep, value = text.partition("=")
    if not sep or not all(part.isidentifier() for part in key.split(".")):
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE (KEY may be dotted), got {text!r}")
    return key, literal(value)


def recorded_args(args: argparse.Namespace) -> dict[str, object]:
    """The parsed command line as results record it: paths as text, without the
    command's handler."""
    recorded = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()}
    recorded.pop("run", None)
    return recorded


@dataclass(frozen=True)
class Command:
    """A subcommand: its one-line help, a longer description, its arguments and its action."""

    help: str
    description: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]
    # True: the command needs the [rl] extra (stable-baselines3, PyTorch) whatever its
    # options; observer_gym.train.cli.main refuses it in one line without them
    needs_rl: bool = False


def command_error(command: str, message: object) -> int:
    """Report a mistake in ``observer-gym COMMAND``'s request; the exit code 2."""
    print(error_line(f"observer-gym {command}", message), file=sys.stderr)
    return 2
