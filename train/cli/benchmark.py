"""The ``observer-gym benchmark`` command's arguments and action (the library is
:mod:`observer_gym.train.experiments.benchmark`: :func:`~observer_gym.train.experiments.
benchmark.run.run_benchmark` and :func:`~observer_gym.train.experiments.benchmark.check.
check_folder`).

Two forms: ``--env ENV --observer O --controller C --out DIR`` runs (or resumes) one
entry on every level of the system's suite; ``--check DIR`` re-derives a finished
folder's scores. A mistake in the request is one line on stderr and exit code 2, with
nothing written; a folder that does not check out is one line and exit code 1.
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
from observer_gym.train.cli.rerun_options import add_rerun_folder_arguments, rerun_folder_options
from observer_gym.train.cli.video_options import add_video_arguments, video_options
from observer_gym.train.core.args import PER_ENV, env_name, folder_path, positive_int
from observer_gym.train.core.messages import error_line
from observer_gym.train.core.signals import INTERRUPTED_EXIT_CODE

PROG = "observer-gym benchmark"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of ``observer-gym benchmark``."""
    parser.add_argument("--env", type=env_name, default=None, help="environment (to run)")
    parser.add_argument(
        "--observer",
        default=None,
        metavar="NAME",
        help="the entry's observer, per env: "
        + PER_ENV["observers"]
        + "; "
        + OUTSIDE_OBSERVERS_HELP,
    )
    parser.add_argument(
        "--controller",
        default=None,
        metavar="NAME",
        help=(
            "the entry's controller, per env: "
            + PER_ENV["controllers"]
            + "; or a trained agent ALGO:DIR (one seed's run); "
            + OUTSIDE_CONTROLLERS_HELP
        ),
    )
    parser.add_argument(
        "--policy",
        default=None,
        metavar="ALGO:DIR",
        help="a trained agent as the entry (one seed's run, or ALGO:NAME of a shipped "
        "agent), in place of --controller: it reads the observer it was trained on unless "
        "--observer is given, and gets the env options it was trained with (image size, "
        "reward shaping) under each level's options",
    )
    add_entry_option_arguments(parser)
    parser.add_argument(
        "--suite", default="v1", metavar="VERSION", help="the suite version (default: %(default)s)"
    )
    parser.add_argument(
        "--episodes",
        type=positive_int,
        default=None,
        metavar="N",
        help="only the first N seeds of each level: a quick run, marked unofficial "
        "(default: the suite's count, official)",
    )
    parser.add_argument(
        "--out",
        type=folder_path,
        default=None,
        metavar="DIR",
        help="output folder; the same command again resumes it (its finished levels are "
        "checked and reused)",
    )
    add_backend_arguments(parser)
    parser.add_argument(
        "--check",
        type=folder_path,
        default=None,
        metavar="DIR",
        help="re-derive a finished benchmark folder's scores from its per-episode records "
        "and the suite; exit 0 if they agree, 1 naming the first difference",
    )
    parser.add_argument(
        "--no-progress",
        action="store_true",
        help="show no progress (default: a bar on a terminal, else one line per finished "
        "level on stderr)",
    )
    add_video_arguments(parser)
    add_rerun_folder_arguments(parser)


def _error(message: object) -> int:
    print(error_line(PROG, message), file=sys.stderr)
    return 2


def _check(args: argparse.Namespace) -> int:
    given = [
        f"--{k}"
        for k in ("env", "observer", "controller", "policy", "out", "episodes")
        if getattr(args, k) is not None
    ]
    if given:
        return _error(f"--check takes no {', '.join(given)}: it checks a finished folder")
    from observer_gym.train.experiments.benchmark.check import FolderCheckError, check_folder

    try:
        print(check_folder(args.check))
    except FolderCheckError as exc:
        print(error_line(PROG, exc), file=sys.stderr)
        return 1
    return 0


def run(args: argparse.Namespace) -> int:
    """Run or check; 0 on success, 2 for a request rejected before anything runs, 75 for
    an ``--out`` another command holds, 1 for a failed episode or a folder that does not
    check out, 130 for Ctrl-C or SIGTERM (the finished levels are kept)."""
    if args.check is not None:
        return _check(args)
    if args.policy is not None:
        if args.controller is not None:
            return _error("give --controller or --policy, not both: both name the entry's actor")
        from observer_gym.train.experiments.benchmark.run import agent_entry

        try:
            trained_on = agent_entry(args.policy).observer
        except ValueError as exc:
            return _error(exc)
        args.controller = args.policy
        if args.observer is None:
            args.observer = trained_on
    missing = [
        f"--{k}" for k in ("env", "observer", "controller", "out") if getattr(args, k) is None
    ]
    if missing:
        return _error(f"{', '.join(missing)} required (or --policy ALGO:DIR, or --check DIR)")
    from observer_gym.train.cli.compare import check_pairs

    try:
        check_pairs(args.env, [args.observer], [args.controller], {})
        videos = video_options(args)
        reruns = rerun_folder_options(args)
    except ValueError as exc:
        return _error(exc)

    # deferred: PyBullet's worlds, the controllers, SciPy, matplotlib
    from observer_gym.train.experiments.benchmark.run import (
        check_benchmark,
        check_out_dir,
        run_benchmark,
    )
    from observer_gym.train.experiments.videos import plan_reruns, plan_videos
    from observer_gym.train.reports.outputs import OutputFolderError

    try:
        request = check_benchmark(
            args.env,
            args.observer,
            args.controller,
            episodes=args.episodes,
            workers=args.workers,
            backend=args.backend,
            address=args.address,
            version=args.suite,
            observer_options=dict(args.observer_option),
            controller_options=dict(args.controller_option),
        )
        if args.out.exists():
            check_out_dir(args.out, request)
        if videos:
            plan_videos(
                **videos,
                episodes=request.episodes,
                env_id=request.suite.env_id,
                observers=[request.observer],
            )
        if reruns:
            plan_reruns(**reruns, episodes=request.episodes)
    except ValueError as exc:
        return _error(exc)
    progress = progress_display(PROG, args.no_progress)
    try:
        result = run_benchmark(
            request,
            args.out,
            progress=progress.bar,
            cli_args=recorded_args(args),
            on_level=progress.lines,
            **videos,
            **reruns,
        )
    except KeyboardInterrupt:
        print(
            f"{PROG}: interrupted; the finished levels are kept in {args.out}: run the same "
            "command again to resume",
            file=sys.stderr,
        )
        return INTERRUPTED_EXIT_CODE
    except OutputFolderError as exc:
        return _error(exc)
    except ValueError as exc:  # a failed episode
        print(error_line(PROG, exc), file=sys.stderr)
        return 1
    print(result.text)
    return 0


COMMAND = Command(
    help="score one observer + controller on every sensor level of a system's benchmark suite",
    description=(
        "Run one entry (--observer and --controller, by name, import path or entry point; "
        "a trained agent as --policy ALGO:DIR, with the observer it was trained on) on every "
        "level of the system's "
        "benchmark suite (--suite, default v1: ideal, lab, field; docs/benchmark.md), on "
        "the suite's fixed seeds, locally in worker processes (--workers) or as Ray tasks. "
        "Writes episodes.csv (one row per episode), scores.json (per level the headline "
        "metric and the normalised score, 1 = the oracle observer with the reference "
        "controller, 0 = the floor, with 95 % intervals; the IQM over levels with its "
        "stratified-bootstrap interval; suite version, seeds, package versions), table.md "
        "and scores.png into --out. Each finished level is saved under DIR/levels/ at "
        "once; the same command again reuses the finished levels (checked). --episodes N "
        "runs fewer episodes: an unofficial result. --check DIR re-derives a folder's "
        "scores and says whether they agree."
    )
    + TRUST_HELP,
    add_arguments=add_arguments,
    run=run,
)
