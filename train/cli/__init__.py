"""The ``observer-gym`` command: one subcommand per entry of :data:`COMMANDS`.

Each subcommand is a thin layer over a library function that tests call directly; to add
one, write its ``add_arguments`` and ``run`` functions and list its module in ``COMMANDS``.

Building the parser imports nothing heavy (:mod:`observer_gym.train.cli.args`), so
``--help`` answers at once. Each ``run`` function checks the whole request first
(:mod:`observer_gym.train.core.checks`, :mod:`observer_gym.train.rl.checks` and the
library's :func:`~observer_gym.train.experiments.request.check_controller`: observers,
controllers, trained agents, env options, training settings), before the heavy imports
(PyTorch, stable-baselines3) and
before any env is built; a mistake, there or in parsing, is one line on stderr,
``observer-gym COMMAND: error: ...``, and exit code 2.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from collections.abc import Sequence
from importlib import metadata

from observer_gym.extras import ExtraNotInstalled, require_rl
from observer_gym.train.cli import (
    benchmark,
    compare,
    demo,
    evaluate,
    listing,
    record,
    reproduce,
    run,
    study,
    sweep,
    train,
)
from observer_gym.train.core.args import Parser
from observer_gym.train.core.messages import error_line, one_line
from observer_gym.train.core.signals import INTERRUPTED_EXIT_CODE, sigterm_as_interrupt

# the subcommands in the order --help lists them
COMMANDS = {
    "demo": demo.COMMAND,
    "run": run.COMMAND,
    "compare": compare.COMMAND,
    "sweep": sweep.COMMAND,
    "train": train.COMMAND,
    "evaluate": evaluate.COMMAND,
    "benchmark": benchmark.COMMAND,
    "record": record.COMMAND,
    "list": listing.COMMAND,
    "reproduce": reproduce.COMMAND,
    "study": study.COMMAND,
}


def _version() -> str:
    try:
        return metadata.version("observer-gym")
    except metadata.PackageNotFoundError:
        return "unknown"


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with one subparser per entry of :data:`COMMANDS`; it
    imports nothing heavy."""
    parser = Parser(
        prog="observer-gym",
        description=(
            "Gymnasium environments in PyBullet controlled through what their cameras see. "
            "Run 'observer-gym COMMAND --help' for a command's options."
        ),
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    subparsers = parser.add_subparsers(
        dest="command", metavar="COMMAND", title="commands", required=True
    )
    for name, command in COMMANDS.items():
        sub = subparsers.add_parser(name, help=command.help, description=command.description)
        command.add_arguments(sub)
        sub.set_defaults(run=command.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``observer-gym``; returns the process exit code.

    argparse raises ``SystemExit`` for ``--help`` (code 0); a mistake in parsing raises
    :class:`~observer_gym.train.core.messages.UsageError` (a ``SystemExit`` with code 2) after
    printing its one line, one found by a command's checks returns 2 after printing its.
    Ctrl-C and SIGTERM stop any command the same way: ``observer-gym COMMAND: interrupted``
    (or the command's own account: ``train`` says how far it got), exit code 130, after
    the file being written, if any, is complete
    (:func:`~observer_gym.train.core.signals.signals_deferred`). A file that cannot be read or
    written (a full disk, no permission: ``OSError``) is one line,
    ``observer-gym COMMAND: error: ...``, and exit code 1; the file is as it was. An
    output folder another command holds (its lock:
    :mod:`observer_gym.train.reports.folder_lock`) is one line naming that command,
    ``observer-gym COMMAND: error: DIR is in use by 'observer-gym sweep' (pid ...)``, and
    exit code 75 (``FOLDER_BUSY_EXIT_CODE``); nothing is written.
    What a command finds left by a killed run in a folder it uses (an
    :class:`~observer_gym.train.reports.outputs.OutputFolderWarning`), and any other
    :class:`~observer_gym.train.reports.outputs.OneLineWarning`, is one line on stderr,
    ``observer-gym COMMAND: warning: ...``; other warnings show as Python shows them.
    A command, observer or agent that needs the ``[rl]`` extra (PyTorch,
    stable-baselines3) where it is not installed is one line naming the install line,
    ``observer-gym COMMAND: error: ... needs PyTorch ...: pip install 'observer-gym[rl]'``,
    and exit code 2, before any env is built (:mod:`observer_gym.extras`).
    """
    args = build_parser().parse_args(argv)
    prog = f"observer-gym {args.command}"
    try:
        if COMMANDS[args.command].needs_rl:
            require_rl("this command")
        return _run(args, prog)
    except ExtraNotInstalled as exc:  # the command, an observer or an agent needs [rl]
        print(error_line(prog, exc), file=sys.stderr)
        return 2


def _run(args: argparse.Namespace, prog: str) -> int:
    """``args.run(args)`` with the warnings, interrupts and file errors of :func:`main`."""
    with warnings.catch_warnings():
        shown = warnings.showwarning

        def show(message, category, filename, lineno, file=None, line=None) -> None:
            # deferred: the warning comes from outputs, loaded by then; --help stays light
            from observer_gym.train.reports.outputs import OneLineWarning

            if issubclass(category, OneLineWarning):
                print(f"{prog}: warning: {one_line(message)}", file=sys.stderr)
            else:
                shown(message, category, filename, lineno, file, line)

        warnings.showwarning = show
        try:
            with sigterm_as_interrupt():
                return args.run(args)
        except KeyboardInterrupt:  # Ctrl-C or SIGTERM where the command does not catch it
            print(f"{prog}: interrupted", file=sys.stderr)
            return INTERRUPTED_EXIT_CODE
        except OSError as exc:  # a file that could not be read or written (a full disk)
            # deferred: the error comes from folder_lock, loaded by then
            from observer_gym.train.reports.folder_lock import (
                FOLDER_BUSY_EXIT_CODE,
                FolderBusyError,
            )

            print(error_line(prog, exc), file=sys.stderr)
            return FOLDER_BUSY_EXIT_CODE if isinstance(exc, FolderBusyError) else 1
