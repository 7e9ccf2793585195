"""``observer-gym evaluate``: score a trained agent with the metrics of 'run'."""

from __future__ import annotations

import argparse
import sys

from observer_gym.train.cli.args import (
    OUTSIDE_OBSERVERS_HELP,
    TRUST_HELP,
    Command,
    add_output_arguments,
    command_error,
    recorded_args,
)
from observer_gym.train.cli.rerun_options import add_rerun_arguments, rerun_options
from observer_gym.train.cli.video_options import add_video_arguments, video_options
from observer_gym.train.core.args import folder_path, nonnegative_int, positive_int
from observer_gym.train.core.messages import error_line


def _evaluate_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--model",
        type=folder_path,
        required=True,
        metavar="DIR",
        help=(
            "the folder of an 'observer-gym train' run; of a multi-seed run (--seeds), every "
            "seed's agent on the same episodes, with the primary metric across seeds; or a "
            "shipped agent, ALGO:NAME or NAME (ppo:ball_table-estimate, see 'observer-gym list')"
        ),
    )
    parser.add_argument(
        "--episodes", type=positive_int, default=10, help="episodes to run (default: %(default)s)"
    )
    parser.add_argument(
        "--seed",
        type=nonnegative_int,
        default=0,
        help="episode i resets with seed + i, as in 'observer-gym run' (default: %(default)s)",
    )
    parser.add_argument(
        "--observer",
        default=None,
        metavar="OBSERVER",
        help="what the agent reads (default: what it was trained on): an observer of its "
        "env (see 'observer-gym list') or " + OUTSIDE_OBSERVERS_HELP,
    )
    parser.add_argument(
        "--steps", type=positive_int, default=None, metavar="K", help="cap each episode at K steps"
    )
    parser.add_argument(
        "--workers", type=positive_int, default=1, metavar="W", help="processes to run in"
    )
    add_output_arguments(parser, "evaluate")
    add_video_arguments(parser)
    add_rerun_arguments(parser)


def _evaluate_run(args: argparse.Namespace) -> int:
    from observer_gym.envs import system_for_id
    from observer_gym.train.core.checks import check_env_options, check_observer, observer_mode
    from observer_gym.train.experiments.request import check_pair_of
    from observer_gym.train.reports.video import check_video_observer
    from observer_gym.train.rl.run_dir import (
        agent_folder,
        is_multi_seed,
        read_config,
        seed_run_dirs,
    )

    try:
        model = agent_folder(args.model)  # a shipped agent by name too
    except ValueError as exc:
        return command_error("evaluate", exc)
    try:
        multi_seed = is_multi_seed(model)  # seed_0 and seed_00 both there: refused
        runs = list(seed_run_dirs(model).values()) if multi_seed else [model]
        for run_dir in runs:
            config = read_config(run_dir)
            observer = args.observer or config["observer"]
            env_id = check_observer(config["env_id"], observer)
            check_pair_of(system_for_id(env_id), observer, f"{config['algo']}:{run_dir}")
            obs_mode = observer_mode(env_id, observer)
            check_env_options(env_id, obs_mode, config["env_kwargs"])
            if args.video is not None:
                check_video_observer(obs_mode, observer)
        videos = video_options(args)
        recording = rerun_options(args)
        if multi_seed and recording:
            raise ValueError(
                "--rerun records one agent's episode: give one seed's run "
                "(--model DIR/seed_<s>), not the multi-seed run"
            )
    except (ValueError, ImportError) as exc:  # no agent there, or an observer it cannot read
        return command_error("evaluate", exc)

    # deferred: torch, PyBullet
    from observer_gym.train.experiments import api
    from observer_gym.train.experiments.evaluate import evaluate_seeds, seeds_evaluation_text
    from observer_gym.train.reports.outputs import default_out_dir

    options = {
        "episodes": args.episodes,
        "out_dir": args.out if args.out is not None else default_out_dir("evaluate"),
        "seed": args.seed,
        "observer": args.observer,
        "steps": args.steps,
        "workers": args.workers,
        "progress": not args.no_progress,
        "cli_args": recorded_args(args),
        **videos,
        **recording,
    }
    try:
        if multi_seed:
            print(seeds_evaluation_text(evaluate_seeds(model, **options)))
        else:
            print(api.evaluate(model, **options).text)
    except ValueError as exc:  # an outside observer that fails its first try, or mid-episode
        print(error_line("observer-gym evaluate", exc), file=sys.stderr)
        return 1
    return 0


COMMAND = Command(
    help="score a trained agent with the metrics and results.json of 'run'",
    description=(
        "Run closed-loop episodes of an agent trained by 'observer-gym train' (--model "
        "DIR) on its env, reading what it was trained on or another --observer, and "
        "write results.json and the env's plots exactly as 'observer-gym run' does for a "
        "baseline controller (episode i resets with seed + i). For a multi-seed run "
        "(train --seeds), every seed's agent runs the same episodes into seed_<s>/, and "
        "across_seeds.md/.json give each seed's mean of the primary metric, their mean "
        "and their IQM with a 95 % interval."
    )
    + TRUST_HELP,
    add_arguments=_evaluate_arguments,
    run=_evaluate_run,
    needs_rl=True,
)
