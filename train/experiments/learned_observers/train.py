"""Train a system's learned observer and write its weights and report.

    python -m observer_gym.train.experiments.learned_observers.train --env BallTable-v0
        [--episodes N] [--rounds 4] [--seed 0] [--epochs 60] [--out FILE.pt]
        [--dataset DIR] [--data DIR]

Collects the system's training episodes (its ``collect`` in this package) in ``--rounds`` rounds
(DAgger: the controller on the truth, then on the estimate of the network fitted to the
rounds before), fits the Gaussian network on all of them
(:func:`~observer_gym.estimation.learned.training.fit`, the last fifth of the episodes
held out: last-round ones) and writes the weights
(default: the shipped file beside the system's observer) and the report beside them:
this command, the data's size, the held-out per-entry RMSE and NEES/dof (after each
round), the wall time. The same command gives the same weights (the same tensors; a file
written under another name differs in its bytes, as ``torch.save`` names its archive after
the file). ``--episodes`` defaults to the system's ``EPISODES`` (else 60) and the
network's width is its ``HIDDEN`` (else 128), both in its ``estimation/<system>/learned.py``.
The shipped weights' reports record the command under its former name,
``python -m observer_gym.estimation.learned.train``: the same arguments give the same
weights here.
Each round is recorded (``observer-gym record``'s Minari format, with each episode's
drawn sensor options in its metadata) into ``--data DIR`` (``DIR/round-K``, new folders;
default ``observer-gym-out/learned-data-STAMP-PID``) and read back
(:mod:`~observer_gym.train.experiments.learned_observers.recorded`); ``--dataset DIR``
reads the first round from a recording made before (``collect(..., out_dir=DIR)``, the
system's ``record_episodes``, or ``observer-gym record`` in the measurements obs mode)
instead of recording it. Needs the ``[record]`` extra besides ``[rl]``. The arrays a
recording gives equal those the collection gave in memory before (TargetFollower's and
BallCatcher's bit for bit, BallTable's with the action feature as the float32 that
reached the env: tests/train/experiments/test_learned_from_dataset.py); the shipped weights were
fitted on the earlier collection.
A mistake is one line on stderr and exit code 2.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

PROG = "python -m observer_gym.train.experiments.learned_observers.train"
# The systems with a learned observer: env id -> (its observer's module: WEIGHTS,
# TRAINING_RANGES, and optionally EPISODES, the default of --episodes, else 60; HIDDEN, the
# network's width, else 128), (its collection's module: collect)
SYSTEMS = {
    "BallTable-v0": ("ball_table.learned", "ball_table"),
    "TargetFollower-v0": ("target_follower.learned", "target_follower"),
    "BallCatcher-v1": ("ball_catcher.learned", "ball_catcher"),
}
DEFAULT_EPISODES = 60


def main(argv: list[str] | None = None) -> int:
    # the package's parser: a mistake is one line (exit code 2), not argparse's usage
    from observer_gym.train.core.args import Parser

    parser = Parser(prog=PROG, description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", required=True, help=f"one of {', '.join(SYSTEMS)}")
    parser.add_argument(
        "--episodes",
        type=int,
        default=None,
        help=f"episodes per round (default: the system's EPISODES, else {DEFAULT_EPISODES})",
    )
    parser.add_argument("--seed", type=int, default=0, help="data and training seed (0)")
    parser.add_argument("--epochs", type=int, default=60, help="passes over the data (60)")
    parser.add_argument(
        "--rounds", type=int, default=4, help="data rounds: 1 on the truth, then DAgger (4)"
    )
    parser.add_argument("--out", type=Path, default=None, help="weight file (.pt)")
    parser.add_argument(
        "--dataset",
        type=Path,
        default=None,
        metavar="DIR",
        help="the first round's episodes: a recording of the system's training episodes "
        "(observer-gym record's Minari format; default: recorded into --data)",
    )
    parser.add_argument(
        "--data",
        type=Path,
        default=None,
        metavar="DIR",
        help="the folder each round's recording is written to, DIR/round-K (default: "
        "observer-gym-out/learned-data-STAMP-PID)",
    )
    args = parser.parse_args(argv)
    from observer_gym.extras import TORCH_MODULES, ExtraNotInstalled, require_rl

    try:
        require_rl(PROG, TORCH_MODULES)
    except ExtraNotInstalled as error:
        print(f"{PROG}: error: {error}", file=sys.stderr)
        return 2
    env_id = args.env.removeprefix("observer_gym/")
    if env_id not in SYSTEMS:
        print(
            f"{PROG}: error: no learned observer for {args.env!r} yet; allowed: "
            f"{', '.join(SYSTEMS)}",
            file=sys.stderr,
        )
        return 2
    import importlib

    observer, collection = SYSTEMS[env_id]
    system = importlib.import_module(f"observer_gym.estimation.{observer}")
    collect = importlib.import_module(f"{__package__}.{collection}").collect
    default_episodes = getattr(system, "EPISODES", DEFAULT_EPISODES)
    if args.episodes is None:
        args.episodes = default_episodes
    if args.episodes < 5 or args.epochs < 1 or args.rounds < 1:
        print(
            f"{PROG}: error: --episodes must be >= 5, --epochs and --rounds >= 1",
            file=sys.stderr,
        )
        return 2
    from observer_gym.extras import require_record

    try:
        require_record(PROG)
    except ExtraNotInstalled as error:
        print(f"{PROG}: error: {error}", file=sys.stderr)
        return 2
    import numpy as np

    from observer_gym.estimation.learned.network import save_network
    from observer_gym.estimation.learned.training import Dataset, fit

    hidden = getattr(system, "HIDDEN", 128)
    out = args.out or system.WEIGHTS
    if out.suffix != ".pt":
        print(f"{PROG}: error: --out must end in .pt, got {out}", file=sys.stderr)
        return 2
    from observer_gym.train.experiments.learned_observers.recorded import training_arrays
    from observer_gym.train.experiments.record import check_new_folder
    from observer_gym.train.reports.outputs import default_out_dir

    records = args.dataset is None or args.rounds > 1  # a round is recorded
    data_dir = (args.data or default_out_dir("learned-data")) if records else None

    def round_data(k: int, act_with: object = None) -> tuple:
        """Round k's arrays (k = 0 the first): recorded into data_dir/round-(k+1) and read
        back."""
        assert data_dir is not None  # a round is recorded
        return collect(
            args.episodes, args.seed + k, act_with=act_with, out_dir=data_dir / f"round-{k + 1}"
        )

    tic = time.perf_counter()
    try:
        if data_dir is not None:  # a round's folder that exists: refused before any runs
            for k in range(args.dataset is not None, args.rounds):
                check_new_folder(data_dir / f"round-{k + 1}")
        # round 1: the controller on the truth (or a recording of it); each later round
        # (DAgger): on the network fitted to every round before, the data of all rounds kept
        if args.dataset is not None:
            data = Dataset(*training_arrays(env_id, args.dataset))
        else:
            data = Dataset(*round_data(0))
    except ValueError as exc:  # a folder that exists, a recording of something else
        print(f"{PROG}: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    net, report = fit(data, args.seed, epochs=args.epochs, hidden=hidden)
    rounds = [report["held_out"]]
    for k in range(1, args.rounds):
        x, y, episode = round_data(k, act_with=net)
        data = Dataset(
            np.concatenate([data.features, x]),
            np.concatenate([data.truth, y]),
            np.concatenate([data.episode, episode + int(data.episode.max()) + 1]),
        )
        net, report = fit(data, args.seed, epochs=args.epochs, hidden=hidden)
        rounds.append(report["held_out"])
    collected_s = time.perf_counter() - tic
    report["rounds_held_out"] = rounds
    words = [PROG, "--env", env_id]
    if args.episodes != default_episodes:
        words += ["--episodes", str(args.episodes)]
    if args.seed != 0:
        words += ["--seed", str(args.seed)]
    if args.epochs != 60:
        words += ["--epochs", str(args.epochs)]
    if args.rounds != 4:
        words += ["--rounds", str(args.rounds)]
    if args.out is not None:
        words += ["--out", str(args.out)]
    if args.dataset is not None:
        words += ["--dataset", str(args.dataset)]
    report = {
        "command": " ".join(words),
        "env": env_id,
        "episodes": args.episodes,
        "rounds": args.rounds,
        "samples": len(data.truth),
        "features": int(data.features.shape[1]),
        "training_ranges": system.TRAINING_RANGES,
        **({} if data_dir is None else {"data": str(data_dir)}),
        **report,
        "collect_s": round(collected_s, 1),
        "total_s": round(time.perf_counter() - tic, 1),
    }
    save_network(net, out, report)
    held = report["held_out"]
    print(
        f"{out}: {report['samples']} samples, held-out NEES/dof {held['nees_per_dof']:.2f}, "
        f"RMSE {', '.join(f'{v:.3g}' for v in held['rmse'])}; {report['total_s']} s"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
