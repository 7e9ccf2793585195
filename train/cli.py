"""The ``observer-gym`` command: one subcommand per entry of :data:`COMMANDS`.

Each subcommand is a thin layer over a library function that tests call directly; to add
one, write its ``add_arguments`` and ``run`` functions and list it in ``COMMANDS``.

Building the parser imports nothing heavy (:mod:`observer_gym.train.cli_args`), so
``--help`` answers at once. Each ``run`` function checks the whole request first
(:mod:`observer_gym.train.checks`: observers, controllers, trained agents, env options,
training settings), before the heavy imports (PyTorch, stable-baselines3, the layers) and
before any env is built; a mistake, there or in parsing, is one line on stderr,
``observer-gym COMMAND: error: ...``, and exit code 2.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import sys
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from importlib import metadata

from observer_gym.train import compare_cli, sweep_cli
from observer_gym.train.cli_args import (
    OUTSIDE_CONTROLLERS_HELP,
    OUTSIDE_OBSERVERS_HELP,
    Parser,
    UsageError,
    add_entry_option_arguments,
    add_env_option_argument,
    add_output_arguments,
    controller_name,
    distinct_seeds,
    env_name,
    error_line,
    folder_path,
    hyperparam_option,
    nonnegative_int,
    one_line,
    positive_float,
    positive_int,
    recorded_args,
)
from observer_gym.train.hyperparams import ALGOS
from observer_gym.train.signals import INTERRUPTED_EXIT_CODE, sigterm_as_interrupt


@dataclass(frozen=True)
class Command:
    """A subcommand: its one-line help, a longer description, its arguments and its action."""

    help: str
    description: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]


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
    add_output_arguments(parser, "demo")


def _error(command: str, message: object) -> int:
    """Report a mistake in ``observer-gym COMMAND``'s request; the exit code 2."""
    print(error_line(f"observer-gym {command}", message), file=sys.stderr)
    return 2


def _demo_run(args: argparse.Namespace) -> int:
    from observer_gym.train import demo  # deferred: imports PyBullet and OpenCV
    from observer_gym.train.outputs import default_out_dir

    out_dir = args.out if args.out is not None else default_out_dir("demo")
    print(demo.INTRODUCTION)
    summary = demo.run_demo(
        out_dir=out_dir,
        seconds=args.seconds,
        seed=args.seed,
        frame_every=args.frame_every,
        progress=not args.no_progress,
    )
    print(demo.summary_text(summary))
    print(f"output: {out_dir}")
    return 0


# --- run -------------------------------------------------------------------------------
def _run_arguments(parser: argparse.ArgumentParser) -> None:
    from observer_gym.train.checks import per_env

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
            + per_env("observers")
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
            + per_env("controllers")
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
        help="output folder (default: ./observer-gym-out/run-YYYYmmdd-HHMMSS)",
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


def _run_run(args: argparse.Namespace) -> int:
    from observer_gym.train.checks import (
        check_controller,
        check_env_options,
        check_observer,
        observer_mode,
    )

    try:
        env_id = check_observer(args.env, args.observer)
        check_controller(args.controller, env_id, args.observer)
        obs_mode = observer_mode(env_id, args.observer)
        check_env_options(env_id, obs_mode, dict(args.env_option))
    except ValueError as exc:  # an observer, controller or env option the env does not take
        return _error("run", exc)

    from observer_gym.train import api  # deferred: the layers
    from observer_gym.train.episode import EpisodeError

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
        )
    except EpisodeError as exc:  # an episode failed part-way: nothing written
        print(error_line("observer-gym run", exc), file=sys.stderr)
        return 1
    except ValueError as exc:  # an outside observer or controller that fails its first try
        return _error("run", exc)
    print(result.text)
    return 0


# --- train -----------------------------------------------------------------------------
# Listed here so that parsing needs no heavy import; train_agent checks them again.
TRAIN_OBS = ("state", "estimate", "rgb")


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
            "estimate, same layout) or rgb (the camera frames: resized, grayscale, stacked) "
            "(not with --resume)"
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
            "kf-latency-measurements; default: the system's filter on --estimate-from)"
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
            "--address)"
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
    "out",
)


def _train_run(args: argparse.Namespace) -> int:
    from observer_gym.train.outputs import default_out_dir
    from observer_gym.train.run_dir import check_resumable, is_multi_seed

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
        if is_multi_seed(args.resume):
            return _train_seeds_run(args)
        if seeds_options:
            return _error(
                "train",
                f"{', '.join(seeds_options)} apply to --seeds (or --resume of a multi-seed "
                f"run); {args.resume} holds a single run",
            )
        run_dir = args.resume
        try:
            check_resumable(run_dir)  # a run there, a checkpoint, and no run writing it
        except ValueError as exc:
            return _error("train", exc)
        from observer_gym.train.training import resume_training, training_text  # deferred

        try:
            state = resume_training(run_dir, args.timesteps, progress=not args.no_progress)
        except ValueError as exc:  # a checkpoint that cannot be loaded, before training
            return _error("train", exc)
        print(training_text(run_dir, state))
        return INTERRUPTED_EXIT_CODE if state["status"] == "interrupted" else 0
    if args.seeds is not None:
        if args.seed is not None:
            return _error("train", "--seed trains one agent, --seeds several: give one of them")
        return _train_seeds_run(args)
    if seeds_options:
        return _error("train", f"{', '.join(seeds_options)} apply to --seeds (several seeds) only")
    run_dir = args.out if args.out is not None else default_out_dir("train")
    args.seed = 0 if args.seed is None else args.seed  # recorded in config.json as before
    options = _train_options(args, run_dir, args.seed)
    try:
        _check_train_options(args, options)
    except ValueError as exc:
        return _error("train", exc)
    from observer_gym.train.training import train_agent, training_text

    cli_args = recorded_args(args)
    state = train_agent(**options, progress=not args.no_progress, cli_args=cli_args)
    print(training_text(run_dir, state))
    return INTERRUPTED_EXIT_CODE if state["status"] == "interrupted" else 0


def _train_options(args: argparse.Namespace, run_dir: object, seed: int) -> dict[str, object]:
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
        "tensorboard": args.tensorboard,
    }


def _check_train_options(args: argparse.Namespace, options: dict[str, object]) -> None:
    """The checks of a new run: the light ones first, then (importing PyTorch and
    stable-baselines3, whose classes know their hyperparameters) ``check_training``."""
    from observer_gym.train.checks import check_training_request, training_overrides

    overrides = training_overrides(
        options["hyperparams"], args.timesteps, args.n_envs, args.vec_env
    )
    check_training_request(
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
    from observer_gym.train.training import check_training  # deferred: PyTorch

    check_training(**options)


def _train_seeds_run(args: argparse.Namespace) -> int:
    """``train --seeds`` (a new multi-seed run) or ``--resume`` of one."""
    from observer_gym.train.aggregate import check_rliable
    from observer_gym.train.checks import check_backend, check_seeds_folder
    from observer_gym.train.outputs import default_out_dir

    backend = args.backend or "local"
    try:
        check_rliable()
        check_backend(backend, args.workers, args.address)
        if args.resume is None:
            out_dir = args.out if args.out is not None else default_out_dir("train")
            check_seeds_folder(out_dir)
            for seed in args.seeds:
                _check_train_options(args, _train_options(args, out_dir / f"seed_{seed}", seed))
    except (ValueError, ImportError) as exc:
        return _error("train", exc)

    from observer_gym.train.seeds import resume_seeds, seeds_text, train_seeds  # deferred

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
        return _error("train", exc)
    except RuntimeError as exc:  # a seed's training raised; the others ran to their end
        print(error_line("observer-gym train", exc), file=sys.stderr)
        return 1
    print(seeds_text(result))
    return INTERRUPTED_EXIT_CODE if result.status == "interrupted" else 0


# --- evaluate --------------------------------------------------------------------------
def _evaluate_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--model",
        type=folder_path,
        required=True,
        metavar="DIR",
        help=(
            "the folder of an 'observer-gym train' run; of a multi-seed run (--seeds), every "
            "seed's agent on the same episodes, with the primary metric across seeds"
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


def _evaluate_run(args: argparse.Namespace) -> int:
    from observer_gym.train.checks import (
        check_controller,
        check_env_options,
        check_observer,
        observer_mode,
    )
    from observer_gym.train.run_dir import is_multi_seed, read_config, seed_run_dirs

    multi_seed = is_multi_seed(args.model)
    runs = list(seed_run_dirs(args.model).values()) if multi_seed else [args.model]
    try:
        if multi_seed:
            from observer_gym.train.aggregate import check_rliable

            check_rliable()
        for run_dir in runs:
            config = read_config(run_dir)
            observer = args.observer or config["observer"]
            env_id = check_observer(config["env_id"], observer)
            check_controller(f"{config['algo']}:{run_dir}", env_id, observer)
            obs_mode = observer_mode(env_id, observer)
            check_env_options(env_id, obs_mode, config["env_kwargs"])
    except (ValueError, ImportError) as exc:  # no agent there, or an observer it cannot read
        return _error("evaluate", exc)

    # deferred: torch, PyBullet
    from observer_gym.train import api
    from observer_gym.train.evaluate import evaluate_seeds, seeds_evaluation_text
    from observer_gym.train.outputs import default_out_dir

    options = {
        "episodes": args.episodes,
        "out_dir": args.out if args.out is not None else default_out_dir("evaluate"),
        "seed": args.seed,
        "observer": args.observer,
        "steps": args.steps,
        "workers": args.workers,
        "progress": not args.no_progress,
        "cli_args": recorded_args(args),
    }
    try:
        if multi_seed:
            print(seeds_evaluation_text(evaluate_seeds(args.model, **options)))
        else:
            print(api.evaluate(args.model, **options).text)
    except ValueError as exc:  # an outside observer that fails its first try, or mid-episode
        print(error_line("observer-gym evaluate", exc), file=sys.stderr)
        return 1
    return 0


# --- reproduce -------------------------------------------------------------------------
def _study_runner(module_name: str) -> Callable[[argparse.Namespace], int]:
    """The ``run`` of the study module ``module_name``, imported when called."""

    def run(args: argparse.Namespace) -> int:
        return importlib.import_module(module_name).run(args)

    return run


def _reproduce_arguments(parser: argparse.ArgumentParser) -> None:
    from observer_gym.train.reproduce import STUDIES
    from observer_gym.train.reproduce.arguments import ARGUMENTS

    studies = parser.add_subparsers(dest="study", metavar="STUDY", title="studies", required=True)
    for name, module_name in STUDIES.items():
        if importlib.util.find_spec(module_name) is None:
            continue  # a study listed before its module landed
        study = ARGUMENTS[name]
        sub = studies.add_parser(name, help=study.description, description=study.description)
        study.add_arguments(sub)
        sub.set_defaults(study_run=_study_runner(module_name))


def _reproduce_run(args: argparse.Namespace) -> int:
    return args.study_run(args)


# --- list ------------------------------------------------------------------------------
LIST_KINDS = ("system", "observer", "controller", "agent")


def _list_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "kind",
        nargs="?",
        choices=LIST_KINDS,
        default=None,
        help="list only these (default: everything)",
    )


def _list_run(args: argparse.Namespace) -> int:
    from observer_gym.train.catalogue import catalogue  # deferred: reads every layer

    items = [item for item in catalogue() if args.kind in (None, item.kind)]
    for kind in LIST_KINDS:
        group = [item for item in items if item.kind == kind]
        if not group:
            continue
        print(f"{kind}s:")
        width = max(len(item.name) for item in group)
        for item in group:
            where = ", ".join(env_id.split("/", 1)[-1] for env_id in item.systems)
            where = "" if kind == "system" else f" ({where})"
            source = "" if item.source == "observer-gym" else f" [{item.source}]"
            print(f"  {item.name:<{width}}  {item.summary}{where}{source}")
    return 0


COMMANDS: dict[str, Command] = {
    "demo": Command(
        help="centre the ball on BallTable-v0 from camera frames: pixel observer + LQR",
        description=(
            "Run observer_gym/BallTable-v0 with camera (rgb) observations: the pixel observer "
            "(VisionObserver: detector + Kalman filters) estimates the state and the LQR "
            "acts on the estimate, from a ball starting 0.1 m from the centre. Writes "
            "frames/frame_XXXX.png, trajectory.png and summary.json into the output folder "
            "and prints the results and its path."
        ),
        add_arguments=_demo_arguments,
        run=_demo_run,
    ),
    "run": Command(
        help="run a controller in closed loop on the true state or an observer's estimate",
        description=(
            "Run closed-loop episodes of an env (--env, default BallTable-v0): the controller "
            "acts on the true state (--observer oracle) or on the Kalman-filter estimate from "
            "the cameras (kf) or from perfect-detector measurements (kf-measurements). "
            "Episode i resets with seed + i and runs until the env ends it. Writes "
            "results.json (config, versions, per-episode metrics, summary) and the plots of "
            "the env's task (with an observer also estimate.png) into the output folder, and "
            "prints a table of the task's summary."
        ),
        add_arguments=_run_arguments,
        run=_run_run,
    ),
    "compare": Command(
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
        ),
        add_arguments=compare_cli.add_arguments,
        run=compare_cli.run,
    ),
    "sweep": Command(
        help="run observers x controllers over a grid of env options (resumable) and plot them",
        description=(
            "Run every observer x controller of --observers and --controllers at every point "
            "of a grid of env options (--vary KEY=V1,V2,..., repeatable: the grid is every "
            "combination) on the same seeds: episode i of every cell resets with seed S + i. "
            "Locally in worker processes (--workers) or as Ray tasks (--backend ray). Each "
            "finished cell is saved under DIR/cells/ at once; running the same command again "
            "skips the finished cells (another command into the same --out is refused). Writes "
            "results.json, episodes.csv (one row per episode), table.md (per cell: the env's "
            "primary metric and a second one with 95 % intervals, and the paired difference "
            "from the first grid point) and <key>.png per varied key into --out, and prints "
            "the table."
        ),
        add_arguments=sweep_cli.add_arguments,
        run=sweep_cli.run,
    ),
    "train": Command(
        help="train a stable-baselines3 agent (PPO, SAC, TD3) on the state, an estimate or pixels",
        description=(
            "Train a stable-baselines3 agent on an env (--env, default BallTable-v0) reading "
            "the true state (--obs state), the VisionObserver's estimate (estimate; from "
            "measurements or camera frames by --estimate-from) or the camera frames (rgb). "
            "Hyperparameters come from the YAML file of the algorithm shipped with the package "
            "(observer_gym/train/hyperparams/ALGO.yml), overridable with --hyperparam. Writes "
            "config.json, periodic checkpoints, eval.csv and curve.png (the evaluation "
            "curve), logs/ and, when finished, model.zip and vecnormalize.pkl. Ctrl-C or kill "
            "leaves the last checkpoint intact; --resume DIR continues from it. --seeds 0,1,2 "
            "trains one agent per seed into OUT/seed_<s>/ (in parallel processes, or Ray "
            "tasks with --backend ray) and writes their aggregate into OUT: "
            "learning_curves.png, aggregate.json and aggregate.md (final evaluation return: "
            "IQM with a stratified-bootstrap 95 % interval, by rliable)."
        ),
        add_arguments=_train_arguments,
        run=_train_run,
    ),
    "evaluate": Command(
        help="score a trained agent with the metrics and results.json of 'run'",
        description=(
            "Run closed-loop episodes of an agent trained by 'observer-gym train' (--model "
            "DIR) on its env, reading what it was trained on or another --observer, and "
            "write results.json and the env's plots exactly as 'observer-gym run' does for a "
            "baseline controller (episode i resets with seed + i). For a multi-seed run "
            "(train --seeds), every seed's agent runs the same episodes into seed_<s>/, and "
            "across_seeds.md/.json give each seed's mean of the primary metric, their mean "
            "and their IQM with a 95 % interval."
        ),
        add_arguments=_evaluate_arguments,
        run=_evaluate_run,
    ),
    "list": Command(
        help="list the systems, observers, controllers and shipped agents, one line each",
        description=(
            "List what the commands take by name: every system (env), observer, controller "
            "and shipped agent, with one line each and the envs it applies to, and the "
            "observers and controllers that installed packages add through the entry-point "
            "groups observer_gym.observers and observer_gym.controllers. Any other observer "
            "or controller is named by import path, package.module:factory."
        ),
        add_arguments=_list_arguments,
        run=_list_run,
    ),
    "reproduce": Command(
        help="re-run a source paper's study and print its figures beside the paper's",
        description=(
            "Re-run the study of one of the source papers in spec/ (linderoth2010: the "
            "viewline Kalman filter's convergence; tsai2009: the self-tuning Kalman filter's "
            "Table 2) and print the measured figures beside the paper's; plots are saved "
            "into the output folder."
        ),
        add_arguments=_reproduce_arguments,
        run=_reproduce_run,
    ),
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
    :class:`~observer_gym.train.cli_args.UsageError` (a ``SystemExit`` with code 2) after
    printing its one line, one found by a command's checks returns 2 after printing its.
    Ctrl-C and SIGTERM stop any command the same way: ``observer-gym COMMAND: interrupted``
    (or the command's own account: ``train`` says how far it got), exit code 130, after
    the file being written, if any, is complete
    (:func:`~observer_gym.train.signals.signals_deferred`). A file that cannot be read or
    written (a full disk, no permission: ``OSError``) is one line,
    ``observer-gym COMMAND: error: ...``, and exit code 1; the file is as it was.
    What a command finds left by a killed run in a folder it uses (an
    :class:`~observer_gym.train.outputs.OutputFolderWarning`), and any other
    :class:`~observer_gym.train.outputs.OneLineWarning`, is one line on stderr,
    ``observer-gym COMMAND: warning: ...``; other warnings show as Python shows them.
    """
    args = build_parser().parse_args(argv)
    prog = f"observer-gym {args.command}"
    with warnings.catch_warnings():
        shown = warnings.showwarning

        def show(message, category, filename, lineno, file=None, line=None) -> None:
            # deferred: the warning comes from outputs, loaded by then; --help stays light
            from observer_gym.train.outputs import OneLineWarning

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
            print(error_line(prog, exc), file=sys.stderr)
            return 1


if __name__ == "__main__":
    raise SystemExit(main())
