"""``observer-gym record``: closed-loop episodes kept as a Minari dataset."""

from __future__ import annotations

import argparse
import sys

from observer_gym.train.cli.args import (
    OUTSIDE_CONTROLLERS_HELP,
    OUTSIDE_OBSERVERS_HELP,
    Command,
    add_entry_option_arguments,
    command_error,
    controller_name,
    randomize_option,
    recorded_args,
)
from observer_gym.train.core.args import (
    PER_ENV,
    add_env_option_argument,
    env_name,
    folder_path,
    nonnegative_int,
    positive_int,
)
from observer_gym.train.core.messages import error_line


def _record_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--env", type=env_name, default="BallTable-v0", help="environment (default: %(default)s)"
    )
    parser.add_argument(
        "--observer",
        required=True,
        metavar="OBSERVER",
        help=(
            "the observer whose env is recorded (its obs mode: frames, measurements or the "
            "state); per env: " + PER_ENV["observers"] + "; " + OUTSIDE_OBSERVERS_HELP
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
            + "; any env: a trained agent as ALGO:DIR; "
            + OUTSIDE_CONTROLLERS_HELP
        ),
    )
    add_entry_option_arguments(parser)
    parser.add_argument(
        "--episodes",
        type=positive_int,
        default=10,
        help="episodes to record (default: %(default)s)",
    )
    parser.add_argument(
        "--seed",
        type=nonnegative_int,
        default=0,
        help=(
            "episode i resets with seed + i; with --randomize the seed of the draws "
            "(default: %(default)s)"
        ),
    )
    parser.add_argument(
        "--out",
        type=folder_path,
        required=True,
        metavar="DIR",
        help="the new folder to write the dataset into (must not exist)",
    )
    parser.add_argument(
        "--steps",
        type=positive_int,
        default=None,
        metavar="K",
        help="cap each episode at K steps (default: the env's time limit)",
    )
    add_env_option_argument(
        parser,
        "a gym.make option of the env, repeatable (e.g. camera_preset=single); the observer "
        "sets obs_mode",
    )
    parser.add_argument(
        "--randomize",
        type=randomize_option,
        action="append",
        default=[],
        metavar="KEY=LOW:HIGH|KEY=A|B",
        help=(
            "draw the env option KEY anew for every episode, repeatable: KEY=LOW:HIGH a "
            "number uniform in [LOW, HIGH] (an integer option: an integer in LOW..HIGH), "
            "KEY=A|B|... one of the values (e.g. latency_s=0:0.05, frame_drop_prob=0:0.2); "
            "the options and then the world's seed of each episode are drawn from one "
            "generator seeded with --seed, as the learned observers' training data are, and "
            "kept in the episode's metadata (seed, drawn_options). Not with --env-option of "
            "the same KEY"
        ),
    )
    parser.add_argument("--no-progress", action="store_true", help="do not show the progress bar")


def _checked_randomize(args: argparse.Namespace, env_id: str) -> dict[str, dict] | None:
    """``--randomize`` checked (each key once, none also an ``--env-option``, every range
    end and choice taken by the env), or None; ValueError naming what is wrong."""
    from observer_gym.train.core.checks import observer_mode
    from observer_gym.train.rl.randomize import check_randomize

    keys = [key for key, _ in args.randomize]
    repeated = sorted({key for key in keys if keys.count(key) > 1})
    if repeated:
        raise ValueError(f"--randomize gives {', '.join(repeated)} more than once; give each once")
    checked = check_randomize(
        env_id,
        observer_mode(env_id, args.observer),
        dict(args.env_option),
        dict(args.randomize),
        fixed=dict(args.env_option),
        fixed_by="--env-option",
    )
    return checked or None


def _run_record(args: argparse.Namespace) -> int:
    from observer_gym.envs import system_for_id
    from observer_gym.extras import require_record
    from observer_gym.train.core.checks import check_env_options, check_observer, observer_mode
    from observer_gym.train.experiments.record import check_new_folder
    from observer_gym.train.experiments.request import check_pair_of

    try:
        env_id = check_observer(args.env, args.observer)
        check_pair_of(system_for_id(env_id), args.observer, args.controller)
        check_env_options(env_id, observer_mode(env_id, args.observer), dict(args.env_option))
        randomize = _checked_randomize(args, env_id)
        check_new_folder(args.out)
    except ValueError as exc:  # an observer, controller, env option or folder refused
        return command_error("record", exc)
    require_record()  # observer_gym.train.cli.main prints its one line, exit code 2

    from observer_gym.train.experiments.episode import EpisodeError
    from observer_gym.train.experiments.record import record_experiment

    try:
        record = record_experiment(
            env_id,
            args.observer,
            args.controller,
            episodes=args.episodes,
            seed=args.seed,
            out_dir=args.out,
            steps=args.steps,
            progress=not args.no_progress,
            env_kwargs=dict(args.env_option),
            observer_options=dict(args.observer_option),
            controller_options=dict(args.controller_option),
            cli_args=recorded_args(args),
            randomize=randomize,
        )
    except EpisodeError as exc:  # an episode failed part-way: nothing written
        print(error_line("observer-gym record", exc), file=sys.stderr)
        return 1
    except ValueError as exc:  # an outside entry that fails its first try
        return command_error("record", exc)
    steps = sum(episode["steps"] for episode in record["episodes"])
    print(
        f"observer-gym record: {env_id}, observer {args.observer}, controller "
        f"{args.controller}, {len(record['episodes'])} episode(s), {steps} steps\n"
        f"dataset {record['dataset_id']} in {args.out}; load it with "
        f"MINARI_DATASETS_PATH={args.out} and minari.load_dataset('{record['dataset_id']}')"
    )
    return 0


COMMAND = Command(
    help="record closed-loop episodes as a Minari dataset",
    description=(
        "Run closed-loop episodes of an env with an observer and a controller (episode i "
        "resets with seed + i; with --randomize each draws its options and world seed) "
        "and keep them as a Minari dataset in a new folder --out: "
        "the observations of the observer's obs mode, the actions, rewards, terminations "
        "and truncations, and in the infos the true state, the frames' capture and "
        "delivery times and calibration, and the observer's estimate and covariance "
        "(docs/record.md). Needs the [record] extra: pip install 'observer-gym[record]'."
    ),
    add_arguments=_record_arguments,
    run=_run_record,
)
