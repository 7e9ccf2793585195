"""``observer-gym study``: studies that train many agents, one subcommand each (the library
is :mod:`observer_gym.train.experiments.delay_rl`).

``observer-gym study delay-rl --env ENV --out DIR`` runs (or, the same command again,
continues) the random-delay study of one system; ``--check DIR`` derives a finished
study's table again from its per-seed records. A mistake in the request is one line on
stderr and exit code 2, with nothing written; a folder that does not check out is one
line and exit code 1.
"""

from __future__ import annotations

import argparse
import sys

from observer_gym.train.cli.args import (
    Command,
    add_backend_arguments,
    progress_display,
    recorded_args,
)
from observer_gym.train.core.args import distinct_seeds, env_name, folder_path, positive_int
from observer_gym.train.core.messages import error_line

PROG = "observer-gym study delay-rl"
# listed here so that parsing needs no heavy import; the plan checks them again
LEVEL_NAMES = ("none", "moderate", "heavy")
INPUT_NAMES = ("newest", "stack", "kf-latency", "kf", "truth", "pixels")


def _names(allowed: tuple[str, ...], kind: str):
    def parse(text: str) -> tuple[str, ...]:
        names = tuple(name.strip() for name in text.split(",") if name.strip())
        unknown = [name for name in names if name not in allowed]
        if not names or unknown:
            raise argparse.ArgumentTypeError(
                f"unknown {kind} {unknown[0] if unknown else text!r}; allowed: "
                f"{', '.join(allowed)} (comma-separated)"
            )
        return names

    return parse


def _delay_rl_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--env", type=env_name, default=None, help="the system (BallTable-v0, BallCatcher-v1)"
    )
    parser.add_argument(
        "--levels",
        type=_names(LEVEL_NAMES, "level"),
        default=LEVEL_NAMES,
        metavar="L,L",
        help="delay levels (default: %(default)s; values in docs/results/delay_rl.md)",
    )
    parser.add_argument(
        "--inputs",
        type=_names(INPUT_NAMES, "input"),
        default=None,
        metavar="I,I",
        help="what the agents read: newest, stack, kf-latency, kf, truth, and on "
        "BallTable pixels (trained at moderate only) (default: all of the system's)",
    )
    parser.add_argument(
        "--seeds",
        type=distinct_seeds,
        default=[0, 1, 2, 3, 4],
        metavar="SEEDS",
        help="training seeds, e.g. 0-4 or 0,1,2 (default: 0-4)",
    )
    parser.add_argument(
        "--timesteps",
        type=positive_int,
        default=None,
        metavar="N",
        help="env steps per seed, the same for every input (default: the system's tuned "
        "PPO budget)",
    )
    parser.add_argument(
        "--eval-episodes",
        type=positive_int,
        default=10,
        metavar="N",
        help="evaluation episodes per agent and level (default: %(default)s)",
    )
    parser.add_argument(
        "--out",
        type=folder_path,
        default=None,
        metavar="DIR",
        help="the study's folder; the same command again continues it",
    )
    add_backend_arguments(parser)
    parser.set_defaults(workers=None)
    parser.add_argument(
        "--check",
        type=folder_path,
        default=None,
        metavar="DIR",
        help="derive a finished study's table again from its per-seed records; exit 0 if "
        "it equals table.json, 1 naming the first difference",
    )
    parser.add_argument(
        "--no-progress",
        action="store_true",
        help="show no progress (default: bars on a terminal, else one line per finished part)",
    )


def _error(message: object) -> int:
    print(error_line(PROG, message), file=sys.stderr)
    return 2


def _check(args: argparse.Namespace) -> int:
    given = [f"--{k}" for k in ("env", "out", "timesteps") if getattr(args, k) is not None]
    if given:
        return _error(f"--check takes no {', '.join(given)}: it checks a finished folder")
    from observer_gym.train.experiments.delay_rl import check_table

    try:
        differences = check_table(args.check)
    except ValueError as exc:
        print(error_line(PROG, exc), file=sys.stderr)
        return 1
    if differences:
        print(error_line(PROG, f"{args.check}: {differences[0]}"), file=sys.stderr)
        return 1
    print(f"{args.check}: the table derived from the records equals table.json")
    return 0


def _delay_rl_run(args: argparse.Namespace) -> int:
    """Run or check; 0 on success, 2 for a request rejected before anything runs, 75 for
    an ``--out`` another command holds, 1 for a failed training or a folder that does not
    check out, 130 for Ctrl-C or SIGTERM (every run keeps its last checkpoint)."""
    if args.check is not None:
        return _check(args)
    missing = [f"--{k}" for k in ("env", "out") if getattr(args, k) is None]
    if missing:
        return _error(f"{', '.join(missing)} required (or --check DIR)")
    from observer_gym.train.core.checks import check_backend
    from observer_gym.train.experiments.delay_rl import StudyPlan, inputs_for
    from observer_gym.train.experiments.delay_rl.run import check_study_folder
    from observer_gym.train.rl.hyperparams import resolve_hyperparams

    try:
        check_backend(args.backend, args.workers, args.address)
        timesteps = args.timesteps or int(
            resolve_hyperparams(args.env, "ppo", "state")["n_timesteps"]
        )
        plan = StudyPlan(
            env_id=args.env,
            levels=tuple(args.levels),
            inputs=tuple(args.inputs or inputs_for(args.env)),
            seeds=tuple(args.seeds),
            timesteps=timesteps,
            eval_episodes=args.eval_episodes,
        )
        check_study_folder(args.out, plan)
    except ValueError as exc:
        return _error(exc)
    from observer_gym.train.experiments.delay_rl import run_study
    from observer_gym.train.experiments.delay_rl.table import TABLE_MD

    display = progress_display(PROG, args.no_progress)
    result = run_study(
        plan,
        args.out,
        workers=args.workers,
        backend=args.backend,
        address=args.address,
        progress=display.bar,
        lines=display.lines,
        cli_args=recorded_args(args),
    )
    print((result.out_dir / TABLE_MD).read_text(encoding="utf-8"))
    print(
        f"{result.trained_runs} seed runs trained, {result.evaluations} evaluations in "
        f"{result.wall_time_s:.0f} s; output: {result.out_dir}"
    )
    return 0


def _study_arguments(parser: argparse.ArgumentParser) -> None:
    studies = parser.add_subparsers(dest="study", metavar="STUDY", title="studies", required=True)
    description = (
        "Train PPO agents reading the newest measurement, a stack of measurements, a "
        "latency-aware filter's belief, the same filter without latency handling, or the "
        "true state, at no, moderate and heavy random camera delay, several seeds each "
        "(BallTable also: the last camera frames, trained at moderate only); "
        "evaluate the moderate level's agents at every level; write the table (IQM and "
        "95 % bootstrap intervals) and learning curves. The same command again continues."
    )
    sub = studies.add_parser(
        "delay-rl",
        help="does an agent need an observer under random delays",
        description=description,
    )
    _delay_rl_arguments(sub)
    sub.set_defaults(study_run=_delay_rl_run)


def _study_run(args: argparse.Namespace) -> int:
    return args.study_run(args)


COMMAND = Command(
    help="run a study that trains many agents (delay-rl: does an agent need an observer)",
    description=(
        "Studies that train and evaluate many agents into one folder, resumably: delay-rl "
        "compares agents reading raw measurements, stacks, a filter's belief or the truth "
        "under random camera delays."
    ),
    add_arguments=_study_arguments,
    run=_study_run,
    needs_rl=True,
)
