"""The options the ``observer-gym`` subcommands share (output folder, progress, backend,
outside entries, ``--randomize``, ``--hyperparam``), their help texts, and a subcommand's
record (:class:`Command`). The parser and the argument types every command line of
``observer_gym.train`` uses are :mod:`observer_gym.train.core.args`.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

from observer_gym.train.core.algorithms import ALGOS
from observer_gym.train.core.args import (
    INSTALLED,
    env_option,
    folder_path,
    literal,
    positive_int,
)
from observer_gym.train.core.messages import error_line


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
    command's handlers."""
    recorded = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()}
    recorded.pop("run", None)
    recorded.pop("study_run", None)  # a study's handler (observer-gym study, reproduce)
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
