"""The ``observer-gym sweep`` command's arguments and action (the library function is
:func:`observer_gym.train.experiments.sweep.run_sweep`).

:func:`run` checks what it can without the heavy imports first: the observers,
controllers and env options (:func:`observer_gym.train.cli.compare.check_pairs`) and the
grid (:func:`observer_gym.train.experiments.sweep_grid.check_grid`: keys, values, every grid point's
configuration). Then it loads the library, which checks the rest and the output folder
(:func:`~observer_gym.train.experiments.sweep_plan.check_sweep`), runs the sweep and prints what it
did.
Every mistake is one line on stderr and exit code 2, with nothing written.
"""

from __future__ import annotations

import argparse
import sys

from observer_gym.train.cli.args import (
    OUTSIDE_CONTROLLERS_HELP,
    OUTSIDE_OBSERVERS_HELP,
    TRUST_HELP,
    Command,
    add_backend_arguments,
    add_entry_option_arguments,
    progress_display,
    recorded_args,
)
from observer_gym.train.cli.compare import check_pairs, name_list
from observer_gym.train.cli.rerun_options import add_rerun_folder_arguments, rerun_folder_options
from observer_gym.train.cli.video_options import add_video_arguments, video_options
from observer_gym.train.core.args import (
    PER_ENV,
    add_env_option_argument,
    env_name,
    folder_path,
    nonnegative_int,
    positive_int,
)
from observer_gym.train.core.messages import error_line
from observer_gym.train.core.signals import INTERRUPTED_EXIT_CODE
from observer_gym.train.experiments.sweep_grid import vary_option

DEFAULT_EPISODES = 10


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of ``observer-gym sweep``."""

    parser.add_argument(
        "--env", type=env_name, default="BallTable-v0", help="environment (default: %(default)s)"
    )
    parser.add_argument(
        "--vary",
        type=vary_option,
        action="append",
        required=True,
        metavar="KEY=V1,V2,...",
        help=(
            "an env option and its values, repeatable; the grid is every combination "
            "(latency_s=0,0.02,0.05; any field of the env's config, e.g. frame_drop_prob, "
            "measurement_noise_px, calib_focal_error, push_rate_hz)"
        ),
    )
    parser.add_argument(
        "--observers",
        type=name_list,
        required=True,
        metavar="LIST",
        help="comma-separated observers, per env: "
        + PER_ENV["observers"]
        + "; "
        + OUTSIDE_OBSERVERS_HELP,
    )
    parser.add_argument(
        "--controllers",
        type=name_list,
        required=True,
        metavar="LIST",
        help=(
            "comma-separated controllers, per env: "
            + PER_ENV["controllers"]
            + "; or a trained agent ALGO:DIR; "
            + OUTSIDE_CONTROLLERS_HELP
        ),
    )
    add_entry_option_arguments(parser)
    parser.add_argument(
        "--episodes",
        type=positive_int,
        default=DEFAULT_EPISODES,
        metavar="N",
        help="episodes per cell (default: %(default)s)",
    )
    parser.add_argument(
        "--seed",
        type=nonnegative_int,
        default=0,
        metavar="S",
        help="episode i of every cell resets with S + i (default: %(default)s)",
    )
    parser.add_argument(
        "--out",
        type=folder_path,
        required=True,
        metavar="DIR",
        help=(
            "output folder; run again with the same arguments to resume it (its finished "
            "cells are checked and reused). One command at a time: while a sweep runs, "
            "another command into DIR is refused (exit code 75)"
        ),
    )
    add_backend_arguments(parser)
    parser.add_argument(
        "--steps",
        type=positive_int,
        default=None,
        metavar="K",
        help="cap each episode at K steps (default: the env's time limit)",
    )
    add_env_option_argument(
        parser, "a fixed gym.make option for every cell, repeatable (e.g. push_rate_hz=0.5)"
    )
    parser.add_argument(
        "--second-metric",
        default=None,
        metavar="METRIC",
        help="the metric beside the primary one in the table and plots (default: the env's second)",
    )
    parser.add_argument(
        "--no-progress",
        action="store_true",
        help="show no progress (default: a bar on a terminal, else one line per finished "
        "cell on stderr)",
    )
    add_video_arguments(parser)
    add_rerun_folder_arguments(parser)


def _error(message: object) -> int:
    print(error_line("observer-gym sweep", message), file=sys.stderr)
    return 2


def run(args: argparse.Namespace) -> int:
    """Run the sweep of ``args``; 0 on success, 2 (with a one-line message on stderr) for
    an input rejected before anything runs (an ``--out`` holding another sweep included,
    also when that sweep wrote it after the first check), 75 for an ``--out`` another
    command holds (:mod:`observer_gym.train.reports.folder_lock`; nothing written), 1 for
    cells that cannot be summarised (no output written), 130 for Ctrl-C or SIGTERM (the
    cells written are kept, each whole). The progress bar shows only on a terminal; off
    one, each finished cell is one line on stderr (neither with ``--no-progress``)."""
    from observer_gym.train.core.checks import observer_mode
    from observer_gym.train.experiments.sweep_grid import check_grid

    env_options = dict(args.env_option)
    try:
        check_pairs(args.env, args.observers, args.controllers, env_options)
        modes = [observer_mode(args.env, o) for o in args.observers]
        check_grid(args.env, args.vary, env_options, modes)
        videos = video_options(args)
        reruns = rerun_folder_options(args)
    except ValueError as exc:
        return _error(exc)

    # deferred: PyBullet's worlds, the controllers, SciPy, matplotlib
    from observer_gym.train.experiments import api
    from observer_gym.train.experiments.sweep_plan import check_sweep
    from observer_gym.train.experiments.videos import plan_reruns, plan_videos
    from observer_gym.train.reports.outputs import OutputFolderError

    options = {
        "env_id": args.env,
        "vary": args.vary,
        "observers": args.observers,
        "controllers": args.controllers,
        "episodes": args.episodes,
        "seed": args.seed,
        "workers": args.workers,
        "backend": args.backend,
        "address": args.address,
        "steps": args.steps,
        "env_kwargs": env_options,
        "second_metric": args.second_metric,
        "observer_options": dict(args.observer_option),
        "controller_options": dict(args.controller_option),
    }
    try:
        check_sweep(**options, out_dir=args.out)
        if videos:
            plan_videos(**videos, episodes=args.episodes, env_id=args.env, observers=args.observers)
        if reruns:
            plan_reruns(**reruns, episodes=args.episodes)
    except ValueError as exc:
        return _error(exc)
    progress = progress_display("observer-gym sweep", args.no_progress)
    try:
        result = api.sweep(
            options.pop("env_id"),
            options.pop("vary"),
            options.pop("observers"),
            options.pop("controllers"),
            env_options=options.pop("env_kwargs"),
            **options,
            out_dir=args.out,
            progress=progress.bar,
            cli_args=recorded_args(args),
            on_cell=progress.lines,
            **videos,
            **reruns,
        )
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM (observer_gym.train.cli.main)
        print(
            f"observer-gym sweep: interrupted; the finished cells are kept in {args.out}: "
            "run the same command again to resume",
            file=sys.stderr,
        )
        return INTERRUPTED_EXIT_CODE
    except OutputFolderError as exc:  # another sweep wrote the folder since it was checked
        return _error(exc)
    except ValueError as exc:  # a failed episode, or cells that cannot be summarised
        print(error_line("observer-gym sweep", exc), file=sys.stderr)
        return 1
    print(result.text)
    return 0


COMMAND = Command(
    help="run observers x controllers over a grid of env options (resumable) and plot them",
    description=(
        "Run every observer x controller of --observers and --controllers at every point "
        "of a grid of env options (--vary KEY=V1,V2,..., repeatable: the grid is every "
        "combination) on the same seeds: episode i of every cell resets with seed S + i. "
        "Locally in worker processes (--workers) or as Ray tasks (--backend ray). Each "
        "finished cell is saved under DIR/cells/ at once; running the same command again "
        "skips the finished cells (each checked against the plan: its grid point, seeds "
        "and the sha256 of its episode records; one that does not match runs again, with "
        "a warning). Another command into the same --out is refused: with other "
        "arguments (exit code 2), or while a command runs there (exit code 75). Writes "
        "results.json, episodes.csv (one row per episode), table.md (per cell: the env's "
        "primary metric and a second one with 95 % intervals, and the paired difference "
        "from the first grid point) and <key>.png per varied key into --out, and prints "
        "the table."
    )
    + TRUST_HELP,
    add_arguments=add_arguments,
    run=run,
)
