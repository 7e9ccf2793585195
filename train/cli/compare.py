"""The ``observer-gym compare`` command's arguments and action (the library function is
:func:`observer_gym.train.experiments.compare.run_comparison`).

The help texts list every system's observers and controllers
(:mod:`observer_gym.train.core.checks` and the library's
:func:`~observer_gym.train.experiments.request.check_controller`). :func:`run` checks each
observer, controller and env option there first, then loads the library (and Ray),
which checks the rest (:func:`~observer_gym.train.experiments.compare.check_comparison`), runs the
comparison and prints what it returns.
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
    add_output_arguments,
    recorded_args,
)
from observer_gym.train.cli.rerun_options import add_rerun_folder_arguments, rerun_folder_options
from observer_gym.train.cli.video_options import add_video_arguments, video_options
from observer_gym.train.core.args import (
    PER_ENV,
    add_env_option_argument,
    env_name,
    nonnegative_int,
    positive_int,
    seed_list,
)
from observer_gym.train.core.messages import error_line

DEFAULT_EPISODES = 10
DEFAULT_SEED = 0


def name_list(text: str) -> list[str]:
    """argparse type: comma-separated names (``oracle,kf``); no empty name."""
    names = [name.strip() for name in text.split(",")]
    if any(not name for name in names):
        raise argparse.ArgumentTypeError(f"expected comma-separated names, got {text!r}")
    return names


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of ``observer-gym compare``."""

    parser.add_argument(
        "--env",
        type=env_name,
        default="BallTable-v0",
        help="environment (default: %(default)s)",
    )
    parser.add_argument(
        "--observers",
        type=name_list,
        required=True,
        metavar="LIST",
        help=(
            "comma-separated observers: oracle (the true state), kf (Kalman filter on the "
            "camera pixels), kf-measurements (the same on perfect-detector measurements); "
            "per env: " + PER_ENV["observers"] + "; " + OUTSIDE_OBSERVERS_HELP
        ),
    )
    parser.add_argument(
        "--controllers",
        type=name_list,
        required=True,
        metavar="LIST",
        help=(
            "comma-separated controllers of the env, per env: "
            + PER_ENV["controllers"]
            + "; or a trained agent ALGO:DIR (ppo:runs/ppo-balltable; a multi-seed run's "
            "DIR: every seed's agent, with the primary metric across seeds) or a shipped one "
            "ALGO:NAME (ppo:ball_table-estimate); " + OUTSIDE_CONTROLLERS_HELP
        ),
    )
    add_entry_option_arguments(parser)
    parser.add_argument(
        "--episodes",
        type=positive_int,
        default=None,
        metavar="N",
        help=f"episodes per pair (default: {DEFAULT_EPISODES})",
    )
    parser.add_argument(
        "--seed",
        type=nonnegative_int,
        default=None,
        metavar="S",
        help=f"episode i of every pair resets with S + i (default: {DEFAULT_SEED})",
    )
    parser.add_argument(
        "--seeds",
        type=seed_list,
        default=None,
        metavar="LIST",
        help="explicit seeds, one episode each: 0-9, 3,7,20-24 (instead of --episodes/--seed)",
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
        parser, "a gym.make option of the env for every pair, repeatable (e.g. push_rate_hz=0.5)"
    )
    add_output_arguments(parser, "compare")
    add_video_arguments(parser)
    add_rerun_folder_arguments(parser)


def _error(message: object) -> int:
    print(error_line("observer-gym compare", message), file=sys.stderr)
    return 2


def check_pairs(
    env_id: str,
    observers: list[str],
    controllers: list[str],
    env_options: dict[str, object],
) -> None:
    """The checks of :mod:`observer_gym.train.core.checks` for every pair and the env options
    with each observer's obs_mode; ValueError naming what is allowed otherwise. Imports
    no layer but the env's module."""
    from observer_gym.envs import system_for_id
    from observer_gym.train.core.checks import check_env_options, check_observer, observer_mode
    from observer_gym.train.experiments.request import check_pair_of
    from observer_gym.train.rl.run_dir import expand_agent

    for observer in observers:
        env_id = check_observer(env_id, observer)
    # a multi-seed run stands for its seeds' agents
    controllers = [agent for name in controllers for agent in expand_agent(name)]
    system = system_for_id(env_id)
    for controller in controllers:
        for observer in observers:
            check_pair_of(system, observer, controller)
    for obs_mode in dict.fromkeys(observer_mode(env_id, observer) for observer in observers):
        check_env_options(env_id, obs_mode, env_options, decided_by="each observer")


def run(args: argparse.Namespace) -> int:
    """Run the comparison of ``args``; 0 on success, 2 (with a one-line message on
    stderr) for an input :func:`check_pairs` or the library rejects before running
    anything."""
    if args.seeds is not None and (args.episodes is not None or args.seed is not None):
        return _error("--seeds lists the seeds: give it alone, without --episodes or --seed")
    if args.seeds is not None:
        seeds = args.seeds
    else:
        first = DEFAULT_SEED if args.seed is None else args.seed
        seeds = list(range(first, first + (args.episodes or DEFAULT_EPISODES)))

    try:
        check_pairs(args.env, args.observers, args.controllers, dict(args.env_option))
        videos = video_options(args)
        reruns = rerun_folder_options(args)
    except ValueError as exc:
        return _error(exc)

    # deferred: PyBullet, the controllers, SciPy
    from observer_gym.train.experiments import api
    from observer_gym.train.experiments.compare import check_comparison
    from observer_gym.train.experiments.videos import plan_reruns, plan_videos
    from observer_gym.train.reports.outputs import OutputFolderError, check_folder_kind

    options = {
        "env_id": args.env,
        "observers": args.observers,
        "controllers": args.controllers,
        "seeds": seeds,
        "workers": args.workers,
        "backend": args.backend,
        "address": args.address,
        "steps": args.steps,
        "env_kwargs": dict(args.env_option),
        "observer_options": dict(args.observer_option),
        "controller_options": dict(args.controller_option),
    }
    try:
        check_comparison(**options)
        if args.out is not None:
            check_folder_kind(args.out, "compare")
        if videos:
            plan_videos(**videos, episodes=len(seeds), env_id=args.env, observers=args.observers)
        if reruns:
            plan_reruns(**reruns, episodes=len(seeds))
    except ValueError as exc:
        return _error(str(exc))
    try:
        result = api.compare(
            options.pop("env_id"),
            options.pop("observers"),
            options.pop("controllers"),
            env_options=options.pop("env_kwargs"),
            **options,
            out_dir=args.out,
            progress=not args.no_progress,
            cli_args=recorded_args(args),
            **videos,
            **reruns,
        )
    except OutputFolderError as exc:  # another command wrote the folder since the check
        return _error(str(exc))
    except ValueError as exc:  # an episode failed, or results cannot be written: nothing written
        print(error_line("observer-gym compare", exc), file=sys.stderr)
        return 1
    print(result.text)
    return 0


COMMAND = Command(
    help="run every observer x controller pair on the same seeds and tabulate the metrics",
    description=(
        "Run every pair of --observers and --controllers on one env (--env, default "
        "BallTable-v0) on the same seeds (episode i of every pair resets with the same "
        "seed), locally in worker processes (--workers) or as Ray tasks (--backend ray). "
        "Controllers include trained agents as ALGO:DIR (a multi-seed run's DIR: one "
        "agent per seed, and a table across seeds). Writes table.md and table.csv "
        "(per pair and metric: mean with its 95 % Student t interval, rates with a "
        "Wilson interval; with 'oracle' among the observers, the paired difference "
        "observer - oracle of the env's primary metric per controller), bar_<metric>.png, "
        "each pair's plots under pairs/ and results.json into the output folder, and "
        "prints the table."
    )
    + TRUST_HELP,
    add_arguments=add_arguments,
    run=run,
)
