"""The ``observer-gym`` command: one subcommand per entry of :data:`COMMANDS`.

Each subcommand is a thin layer over a library function that tests call directly; to add
one, write its ``add_arguments`` and ``run`` functions and list it in ``COMMANDS``.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path


@dataclass(frozen=True)
class Command:
    """A subcommand: its one-line help, a longer description, its arguments and its action."""

    help: str
    description: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text}")
    return value


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1, got {text}")
    return value


# --- demo ------------------------------------------------------------------------------
def _demo_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--seconds",
        type=positive_float,
        default=10.0,
        help="simulated duration in seconds, 50 steps per second (default: %(default)s)",
    )
    parser.add_argument("--seed", type=int, default=0, help="reset seed (default: %(default)s)")
    parser.add_argument(
        "--frame-every",
        type=positive_int,
        default=50,
        metavar="N",
        help="save the camera frame every N steps (default: %(default)s)",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        metavar="DIR",
        help="output folder (default: ./observer-gym-out/demo-YYYYmmdd-HHMMSS)",
    )
    parser.add_argument("--no-progress", action="store_true", help="do not show the progress bar")


def _demo_run(args: argparse.Namespace) -> int:
    from observer_gym.train.demo import run_demo  # deferred: imports PyBullet and OpenCV

    run_demo(
        out_dir=args.out,
        seconds=args.seconds,
        seed=args.seed,
        frame_every=args.frame_every,
        progress=not args.no_progress,
    )
    return 0


COMMANDS: dict[str, Command] = {
    "demo": Command(
        help="run BallTable-v0 under a scripted tilt; save frames, a plot and a summary",
        description=(
            "Run observer_gym/BallTable-v0 with camera (rgb) observations for a few seconds. "
            "No controller exists yet: the table follows a SCRIPTED, open-loop tilt meant to "
            "roll the ball around a 0.06 m circle, so the ball drifts. Writes "
            "frames/frame_XXXX.png, trajectory.png and summary.json into the output folder "
            "and prints its path."
        ),
        add_arguments=_demo_arguments,
        run=_demo_run,
    ),
}


def _version() -> str:
    try:
        return metadata.version("observer-gym")
    except metadata.PackageNotFoundError:
        return "unknown"


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with one subparser per entry of :data:`COMMANDS`."""
    parser = argparse.ArgumentParser(
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

    argparse raises ``SystemExit`` for ``--help`` (code 0) and for bad arguments (code 2).
    """
    args = build_parser().parse_args(argv)
    return args.run(args)


if __name__ == "__main__":
    raise SystemExit(main())
