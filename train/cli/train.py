"""``observer-gym train``: train a stable-baselines3 agent, one seed or several, and resume one."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import Any

from observer_gym.train.cli.args import (
    Command,
    add_output_arguments,
    command_error,
    hyperparam_option,
    randomize_option,
    recorded_args,
)
from observer_gym.train.core.algorithms import ALGOS
from observer_gym.train.core.args import (
    add_env_option_argument,
    distinct_seeds,
    env_name,
    folder_path,
    nonnegative_int,
    positive_int,
)
from observer_gym.train.core.messages import UsageError, error_line
from observer_gym.train.core.signals import INTERRUPTED_EXIT_CODE

# Listed here so that parsing needs no heavy import; train_agent checks them again.
TRAIN_OBS = ("state", "estimate", "rgb", "measurements")


class _ResumeAction(argparse.Action):
    """``--resume DIR``: the run in DIR brings its own settings, so the options it
    names in ``relaxes`` (--algo, --obs) are no longer required."""

    def __init__(self, *args, relaxes: Sequence[argparse.Action] = (), **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.relaxes = tuple(relaxes)

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        setattr(namespace, self.dest, values)
        for action in self.relaxes:
            action.required = False


def _train_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--env", type=env_name, default="BallTable-v0", help="environment (default: %(default)s)"
    )
    algo = parser.add_argument(
        "--algo",
        choices=ALGOS,
        required=True,
        help="stable-baselines3 algorithm (not with --resume)",
    )
    obs = parser.add_argument(
        "--obs",
        choices=TRAIN_OBS,
        required=True,
        help=(
            "what the agent reads: state (the true state), estimate (the VisionObserver's "
            "estimate, same layout), rgb (the camera frames: resized, grayscale, stacked) "
            "or measurements (the newest frame's detections with their ages, unfiltered; "
            "hyperparameter measurement_stack=K: the last K) (not with --resume)"
        ),
    )
    parser.add_argument(
        "--estimate-from",
        choices=("measurements", "rgb"),
        default="measurements",
        help="for --obs estimate: the observer's input (default: %(default)s, no rendering)",
    )
    parser.add_argument(
        "--observer",
        default=None,
        metavar="NAME",
        help=(
            "for --obs estimate: the observer by name, as run and compare take it (e.g. "
            "kf-latency-measurements, or an import path package.module:factory; default: the "
            "system's filter on --estimate-from)"
        ),
    )
    parser.add_argument(
        "--timesteps",
        type=positive_int,
        default=None,
        metavar="N",
        help="env steps to train for in total (default: the YAML's n_timesteps)",
    )
    parser.add_argument(
        "--seed",
        type=nonnegative_int,
        default=None,
        metavar="S",
        help="the run's seed (default: 0)",
    )
    parser.add_argument(
        "--seeds",
        type=distinct_seeds,
        default=None,
        metavar="LIST",
        help=(
            "train one agent per seed (0,1,2 or 0-4) into OUT/seed_<s>/, in parallel, and "
            "write their aggregate into OUT: learning_curves.png, aggregate.json and "
            "aggregate.md (IQM with a bootstrap interval; pip install 'observer-gym[rl]')"
        ),
    )
    parser.add_argument(
        "--workers",
        type=positive_int,
        default=None,
        metavar="W",
        help="with --seeds: train W seeds at once (default: one per seed, at most the CPUs)",
    )
    parser.add_argument(
        "--backend",
        choices=("local", "ray"),
        default=None,
        help=(
            "with --seeds: local processes, or one Ray task per seed (pip install "
            "'observer-gym[distributed]') (default: local)"
        ),
    )
    parser.add_argument(
        "--address",
        default=None,
        metavar="ADDR",
        help=(
            "with --backend ray: the Ray cluster ('auto' or HOST:PORT; OUT must be on a file "
            "system every node shares) (default: start a local Ray instance)"
        ),
    )
    parser.add_argument(
        "--n-envs", type=positive_int, default=None, metavar="N", help="parallel training envs"
    )
    parser.add_argument(
        "--vec-env",
        choices=("subproc", "dummy"),
        default=None,
        help="SubprocVecEnv (spawned processes) or DummyVecEnv (default: the YAML's)",
    )
    parser.add_argument(
        "--hyperparam",
        type=hyperparam_option,
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help=(
            "override a YAML hyperparameter, repeatable (learning_rate=1e-4, "
            "policy_kwargs.net_arch=[128,128], normalize=False)"
        ),
    )
    add_env_option_argument(parser, "a gym.make option of the env, repeatable; --obs sets obs_mode")
    parser.add_argument(
        "--randomize",
        type=randomize_option,
        action="append",
        default=[],
        metavar="KEY=LOW:HIGH|KEY=A|B",
        help=(
            "domain randomisation, repeatable: every training episode draws the env option "
            "KEY anew, KEY=LOW:HIGH a number uniform in [LOW, HIGH] (an integer option: an "
            "integer in LOW..HIGH), KEY=A|B|... one of the values, each equally likely (e.g. "
            "latency_s=0:0.01, camera_preset='alternating|random_offsets', "
            "air_drag='False|True'). The world is rebuilt with the drawn options at every "
            "reset; the draws come from the run's seed. Not with --env-option of the same "
            "KEY; recorded in config.json and continued by --resume; the evaluation curve, "
            "evaluate, run, compare and benchmark use the fixed options"
        ),
    )
    parser.add_argument(
        "--tensorboard", action="store_true", help="also write TensorBoard logs (logs/)"
    )
    parser.add_argument(
        "--resume",
        type=folder_path,
        default=None,
        metavar="DIR",
        action=_ResumeAction,
        relaxes=(algo, obs),
        help=(
            "continue the run in DIR from its last checkpoint, with its own settings "
            "(takes only --timesteps; then --algo and --obs are not needed); for a "
            "multi-seed run, every unfinished seed (also takes --workers, --backend, "
            "--address). One command at a time: while a run trains in DIR, another "
            "--resume of it is refused (exit code 75). The checkpoint's model (a "
            "stable-baselines3 zip) and, for SAC and TD3, its replay buffer are pickles, "
            "loaded after their sha256 is checked: resume only runs from a source you "
            "trust; VecNormalize statistics are read as plain arrays"
        ),
    )
    add_output_arguments(parser, "train")


# options a resumed run takes from its config.json instead
_TRAIN_RUN_OPTIONS = (
    "algo",
    "obs",
    "seed",
    "seeds",
    "observer",
    "n_envs",
    "vec_env",
    "hyperparam",
    "env_option",
    "randomize",
    "out",
)


def _train_run(args: argparse.Namespace) -> int:
    from observer_gym.train.reports.outputs import default_out_dir
    from observer_gym.train.rl.run_dir import check_resumable, is_multi_seed

    seeds_options = [
        f"--{k}" for k in ("workers", "backend", "address") if getattr(args, k) is not None
    ]
    if args.resume is not None:
        given = [f"--{k.replace('_', '-')}" for k in _TRAIN_RUN_OPTIONS if getattr(args, k)]
        if args.seed is not None and "--seed" not in given:
            given.append("--seed")
        if given:
            line = error_line(
                "observer-gym train",
                "--resume continues a run with its own settings; drop " + ", ".join(given),
            )
            print(line, file=sys.stderr)
            raise UsageError(line)
        try:
            multi_seed = is_multi_seed(args.resume)  # seed_0 and seed_00: refused
        except ValueError as exc:
            return command_error("train", exc)
        if multi_seed:
            return _train_seeds_run(args)
        if seeds_options:
            return command_error(
                "train",
                f"{', '.join(seeds_options)} apply to --seeds (or --resume of a multi-seed "
                f"run); {args.resume} holds a single run",
            )
        run_dir = args.resume
        try:
            check_resumable(run_dir)  # a run there, a checkpoint, and no run writing it
        except ValueError as exc:
            return command_error("train", exc)
        from observer_gym.train.rl.training import resume_training, training_text  # deferred

        try:
            state = resume_training(run_dir, args.timesteps, progress=not args.no_progress)
        except ValueError as exc:  # a checkpoint that cannot be loaded, before training
            return command_error("train", exc)
        print(training_text(run_dir, state))
        return INTERRUPTED_EXIT_CODE if state["status"] == "interrupted" else 0
    if args.seeds is not None:
        if args.seed is not None:
            return command_error(
                "train", "--seed trains one agent, --seeds several: give one of them"
            )
        return _train_seeds_run(args)
    if seeds_options:
        return command_error(
            "train", f"{', '.join(seeds_options)} apply to --seeds (several seeds) only"
        )
    run_dir = args.out if args.out is not None else default_out_dir("train")
    args.seed = 0 if args.seed is None else args.seed  # recorded in config.json as before
    options = _train_options(args, run_dir, args.seed)
    try:
        _check_train_options(args, options)
    except ValueError as exc:
        return command_error("train", exc)
    from observer_gym.train.rl.training import train_agent, training_text

    cli_args = recorded_args(args)
    try:
        state = train_agent(**options, progress=not args.no_progress, cli_args=cli_args)
    except ValueError as exc:  # another train wrote a run there since the check
        # (OutputFolderError), or the algorithm refused its hyperparameters
        return command_error("train", exc)
    print(training_text(run_dir, state))
    return INTERRUPTED_EXIT_CODE if state["status"] == "interrupted" else 0


def _train_options(args: argparse.Namespace, run_dir: object, seed: int) -> dict[str, Any]:
    """The keywords of ``train_agent`` that ``args`` give, for a run in ``run_dir``."""
    return {
        "env_id": args.env,
        "algo": args.algo,
        "obs": args.obs,
        "out_dir": run_dir,
        "timesteps": args.timesteps,
        "seed": seed,
        "estimate_from": args.estimate_from,
        "observer": args.observer,
        "n_envs": args.n_envs,
        "vec_env": args.vec_env,
        "hyperparams": dict(args.hyperparam),
        "env_kwargs": dict(args.env_option),
        "randomize": dict(args.randomize) or None,
        "tensorboard": args.tensorboard,
    }


def _check_train_options(args: argparse.Namespace, options: dict[str, Any]) -> None:
    """The checks of a new run: the light ones first, then (importing PyTorch and
    stable-baselines3, whose classes know their hyperparameters) ``check_training``."""
    from observer_gym.train.rl.checks import check_training_request, training_overrides

    keys = [key for key, _ in args.randomize]
    repeated = sorted({key for key in keys if keys.count(key) > 1})
    if repeated:
        raise ValueError(f"--randomize gives {', '.join(repeated)} more than once; give each once")
    fixed = sorted(set(keys) & set(options["env_kwargs"]))
    if fixed:
        raise ValueError(
            f"--randomize and --env-option both give {', '.join(fixed)}: an option is either "
            "drawn every episode or fixed"
        )
    overrides = training_overrides(
        options["hyperparams"], args.timesteps, args.n_envs, args.vec_env
    )
    params = check_training_request(
        args.env,
        args.algo,
        args.obs,
        args.estimate_from,
        options["out_dir"],
        overrides,
        options["env_kwargs"],
        args.tensorboard,
        args.observer,
    )
    if options["randomize"]:  # both ends of every range, without PyTorch
        from observer_gym.train.core.checks import agent_observer, observer_mode
        from observer_gym.train.rl.randomize import check_randomize

        observer = agent_observer(args.env, args.obs, args.estimate_from, args.observer)
        check_randomize(
            args.env,
            observer_mode(args.env, observer),
            {**params["env_kwargs"], **options["env_kwargs"]},
            options["randomize"],
        )
    from observer_gym.train.rl.training import check_training  # deferred: PyTorch

    check_training(**options)


def _train_seeds_run(args: argparse.Namespace) -> int:
    """``train --seeds`` (a new multi-seed run) or ``--resume`` of one."""
    from observer_gym.train.core.checks import check_backend
    from observer_gym.train.reports.outputs import default_out_dir
    from observer_gym.train.rl.checks import check_seeds_folder

    backend = args.backend or "local"
    try:
        check_backend(backend, args.workers, args.address)
        if args.resume is None:
            out_dir = args.out if args.out is not None else default_out_dir("train")
            check_seeds_folder(out_dir)
            for seed in args.seeds:
                _check_train_options(args, _train_options(args, out_dir / f"seed_{seed}", seed))
    except (ValueError, ImportError) as exc:
        return command_error("train", exc)

    from observer_gym.train.rl.seeds import resume_seeds, seeds_text, train_seeds  # deferred

    progress = not args.no_progress
    run = {"workers": args.workers, "backend": backend, "address": args.address}
    try:
        if args.resume is not None:
            result = resume_seeds(args.resume, args.timesteps, progress=progress, **run)
        else:
            options = _train_options(args, out_dir, 0)
            del options["seed"]
            cli_args = recorded_args(args)
            result = train_seeds(
                **options, seeds=args.seeds, progress=progress, cli_args=cli_args, **run
            )
    except ValueError as exc:  # found by the checks, before any training
        return command_error("train", exc)
    except RuntimeError as exc:  # a seed's training raised; the others ran to their end
        print(error_line("observer-gym train", exc), file=sys.stderr)
        return 1
    print(seeds_text(result))
    return INTERRUPTED_EXIT_CODE if result.status == "interrupted" else 0


COMMAND = Command(
    help="train a stable-baselines3 agent (PPO, SAC, TD3) on the state, an estimate or pixels",
    description=(
        "Train a stable-baselines3 agent on an env (--env, default BallTable-v0) reading "
        "the true state (--obs state), the VisionObserver's estimate (estimate; from "
        "measurements or camera frames by --estimate-from) or the camera frames (rgb). "
        "Hyperparameters come from the YAML file of the algorithm shipped with the package "
        "(observer_gym/train/rl/hyperparams/ALGO.yml), overridable with --hyperparam. Writes "
        "config.json, periodic checkpoints, eval.csv and curve.png (the evaluation "
        "curve), logs/ and, when finished, model.zip, vecnormalize.npz and final.json (their "
        "sha256). Ctrl-C or kill "
        "leaves the last checkpoint intact; --resume DIR continues from it. A run holds "
        "its folder's lock while it trains (released when it ends, killed or not): "
        "another train or --resume into the same folder is refused with one line and "
        "exit code 75. --seeds 0,1,2 "
        "trains one agent per seed into OUT/seed_<s>/ (in parallel processes, or Ray "
        "tasks with --backend ray) and writes their aggregate into OUT: "
        "learning_curves.png, aggregate.json and aggregate.md (final evaluation return: "
        "IQM with a stratified-bootstrap 95 % interval, rliable's method)."
    ),
    add_arguments=_train_arguments,
    run=_train_run,
    needs_rl=True,
)
