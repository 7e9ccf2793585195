"""``observer-gym run``: closed-loop episodes of one observer and controller."""

from __future__ import annotations

import argparse
import sys

from observer_gym.train.cli.args import (
    OUTSIDE_CONTROLLERS_HELP,
    OUTSIDE_OBSERVERS_HELP,
    TRUST_HELP,
    Command,
    add_entry_option_arguments,
    command_error,
    controller_name,
    recorded_args,
)
from observer_gym.train.cli.rerun_options import add_rerun_arguments, rerun_options
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


def _run_arguments(parser: argparse.ArgumentParser) -> None:

    parser.add_argument(
        "--env",
        type=env_name,
        default="BallTable-v0",
        help="environment (default: %(default)s)",
    )
    parser.add_argument(
        "--observer",
        required=True,
        metavar="OBSERVER",
        help=(
            "what the controller sees: oracle (the true state), kf (Kalman-filter estimate "
            "from camera pixels), kf-measurements (the same from perfect-detector pixel "
            "measurements, no rendering); per env: "
            + PER_ENV["observers"]
            + "; "
            + OUTSIDE_OBSERVERS_HELP
        ),
    )
    parser.add_argument(
        "--controller",
        type=controller_name,
        required=True,
        metavar="CONTROLLER",
        help=(
            "the env's controller, per env: "
            + PER_ENV["controllers"]
            + "; any env: a trained agent as ALGO:DIR (ppo:runs/x) or a shipped one as "
            "ALGO:NAME (ppo:ball_table-estimate); " + OUTSIDE_CONTROLLERS_HELP
        ),
    )
    add_entry_option_arguments(parser)
    parser.add_argument(
        "--episodes", type=positive_int, default=10, help="episodes to run (default: %(default)s)"
    )
    parser.add_argument(
        "--seed",
        type=nonnegative_int,
        default=0,
        help="episode i resets with seed + i (default: %(default)s)",
    )
    parser.add_argument(
        "--out",
        type=folder_path,
        default=None,
        metavar="DIR",
        help="output folder (default: ./observer-gym-out/run-YYYYmmdd-HHMMSS-PID)",
    )
    parser.add_argument(
        "--steps",
        type=positive_int,
        default=None,
        metavar="K",
        help="cap each episode at K steps (default: the env's time limit)",
    )
    parser.add_argument(
        "--workers",
        type=positive_int,
        default=1,
        metavar="W",
        help="run the episodes in W processes; results are identical (default: %(default)s)",
    )
    add_env_option_argument(
        parser,
        "a gym.make option of the env, repeatable (e.g. camera_preset=single, "
        "robot_profile=fast); the observer sets obs_mode",
    )
    parser.add_argument("--no-progress", action="store_true", help="do not show the progress bar")
    add_video_arguments(parser)
    add_rerun_arguments(parser)


def _run_run(args: argparse.Namespace) -> int:
    from observer_gym.envs import system_for_id
    from observer_gym.train.core.checks import check_env_options, check_observer, observer_mode
    from observer_gym.train.experiments.request import check_pair_of

    try:
        env_id = check_observer(args.env, args.observer)
        check_pair_of(system_for_id(env_id), args.observer, args.controller)
        obs_mode = observer_mode(env_id, args.observer)
        check_env_options(env_id, obs_mode, dict(args.env_option))
        videos = video_options(args)
        recording = rerun_options(args)
    except ValueError as exc:  # an observer, controller or env option the env does not take
        return command_error("run", exc)

    from observer_gym.train.experiments import api  # deferred: the layers
    from observer_gym.train.experiments.episode import EpisodeError

    try:
        result = api.run(
            args.env,
            args.observer,
            args.controller,
            episodes=args.episodes,
            seed=args.seed,
            out_dir=args.out,
            steps=args.steps,
            workers=args.workers,
            env_options=dict(args.env_option),
            observer_options=dict(args.observer_option),
            controller_options=dict(args.controller_option),
            progress=not args.no_progress,
            cli_args=recorded_args(args),
            **videos,
            **recording,
        )
    except EpisodeError as exc:  # an episode failed part-way: nothing written
        print(error_line("observer-gym run", exc), file=sys.stderr)
        return 1
    except ValueError as exc:  # an outside observer or controller that fails its first try
        return command_error("run", exc)
    print(result.text)
    return 0


COMMAND = Command(
    help="run a controller in closed loop on the true state or an observer's estimate",
    description=(
        "Run closed-loop episodes of an env (--env, default BallTable-v0): the controller "
        "acts on the true state (--observer oracle) or on the Kalman-filter estimate from "
        "the cameras (kf) or from perfect-detector measurements (kf-measurements). "
        "Episode i resets with seed + i and runs until the env ends it. Writes "
        "results.json (config, versions, per-episode metrics, summary) and the plots of "
        "the env's task (with an observer also estimate.png) into the output folder, and "
        "prints a table of the task's summary."
    )
    + TRUST_HELP,
    add_arguments=_run_arguments,
    run=_run_run,
)
