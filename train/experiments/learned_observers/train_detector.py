"""Train a system's learned detector (the network that reads frames for the ``learned``
and ``learned-kf`` observers) and write its weights and report.

    python -m observer_gym.train.experiments.learned_observers.train_detector --env BallTable-v0
        [--episodes N] [--seed 0] [--epochs N] [--out FILE.pt] [--cache FILE.npz]

Collects the system's lockstep frames (its ``collect_frames`` in this package), fits the
network (:func:`~observer_gym.estimation.learned.frame_training.fit_detector`, or the
system's own ``fit``: BallCatcher's full-resolution heat-map detector,
:mod:`~observer_gym.estimation.learned.heatmap_detector`; the last fifth of the episodes
held out; ``--epochs`` defaults to the system's ``EPOCHS``, else 20) and writes the
weights (default: the shipped file beside the system's observer) and the report beside
them: this command, the data's size, the held-out per-value RMSE (px), NEES/dof and
detected-flag accuracy, the wall times. The same command gives the same tensors.
``--cache`` keeps the collected frames (most of the wall time: rendering) in a file and
reads them back when it holds the same system, episodes and seed, so a refit costs only
the fit; it does not change the weights, and is left out of the recorded command. A file
that holds other frames is refused, not overwritten. A mistake is one line on stderr and
exit code 2. The shipped weights' reports record the command under its former name,
``python -m observer_gym.estimation.learned.train_detector``: the same arguments give the
same tensors here.
"""

from __future__ import annotations

import importlib
import sys
import time
from pathlib import Path
from typing import Any

PROG = "python -m observer_gym.train.experiments.learned_observers.train_detector"
# The systems with a learned detector: env id -> (its detector's module: CAMERA_PX,
# EPISODES, FRAME_RANGES, WEIGHTS, and VALUE_PARTS for frame_detector's network; a system
# with a network of its own gives fit(data, seed, epochs) -> (net, report), save(net,
# path, report) and its default EPOCHS), (its collection's module: collect_frames)
SYSTEMS = {
    "BallTable-v0": ("ball_table.learned_detector", "ball_table"),
    "TargetFollower-v0": ("target_follower.learned_detector", "target_follower"),
    "BallCatcher-v1": ("ball_catcher.learned_detector", "ball_catcher"),
}
DEFAULT_EPOCHS = 20


def _fail(message: str) -> int:
    print(f"{PROG}: error: {message}", file=sys.stderr)
    return 2


def _frames(collect_frames: Any, env_id: str, episodes: int, seed: int, cache: Path | None) -> Any:
    """The system's collected frames: read from ``cache`` if it exists, else collected
    with ``collect_frames(episodes, seed)`` (and written to ``cache``).

    Raises:
        ValueError: ``cache`` holds the frames of another (env, episodes, seed), or is no
            frame file of this command.
    """
    import numpy as np

    from observer_gym.estimation.learned.frame_training import FrameDataset

    key = np.array([env_id, str(episodes), str(seed)])
    if cache is not None and cache.is_file():
        with np.load(cache) as saved:
            found = saved["key"].tolist() if "key" in saved else None
            if found != key.tolist():
                raise ValueError(
                    f"--cache {cache} holds the frames of (env, episodes, seed) = {found}, "
                    f"not {key.tolist()}: name another file, or remove it to collect again"
                )
            return FrameDataset(*(saved[name] for name in FrameDataset._fields))
    data = collect_frames(episodes, seed)
    if cache is not None:
        cache.parent.mkdir(parents=True, exist_ok=True)
        np.savez(cache, key=key, **data._asdict())
    return data


def main(argv: list[str] | None = None) -> int:
    # the package's parser: a mistake is one line (exit code 2), not argparse's usage
    from observer_gym.train.cli.args import Parser, nonnegative_int

    parser = Parser(prog=PROG, description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", required=True, help=f"one of {', '.join(SYSTEMS)}")
    parser.add_argument(
        "--episodes", type=nonnegative_int, default=None, help="(the system's EPISODES)"
    )
    parser.add_argument(
        "--seed", type=nonnegative_int, default=0, help="data and training seed (0)"
    )
    parser.add_argument(
        "--epochs",
        type=nonnegative_int,
        default=None,
        help=f"passes (the system's, else {DEFAULT_EPOCHS})",
    )
    parser.add_argument("--out", type=Path, default=None, help="weight file (.pt)")
    parser.add_argument(
        "--cache", type=Path, default=None, help="the collected frames, kept and reused (.npz)"
    )
    args = parser.parse_args(argv)
    env_id = args.env.removeprefix("observer_gym/")
    if env_id not in SYSTEMS:
        return _fail(f"no learned detector for {args.env!r} yet; allowed: {', '.join(SYSTEMS)}")
    detector, collection = SYSTEMS[env_id]
    system = importlib.import_module(f"observer_gym.estimation.{detector}")
    collect_frames = importlib.import_module(f"{__package__}.{collection}").collect_frames
    episodes = system.EPISODES if args.episodes is None else args.episodes
    default_epochs = getattr(system, "EPOCHS", DEFAULT_EPOCHS)
    epochs = default_epochs if args.epochs is None else args.epochs
    if episodes < 5 or epochs < 1:
        return _fail("--episodes must be >= 5 and --epochs >= 1")
    out = args.out or system.WEIGHTS
    if out.suffix != ".pt":
        return _fail(f"--out must end in .pt, got {out}")
    if args.cache is not None and args.cache.suffix != ".npz":
        return _fail(f"--cache must end in .npz, got {args.cache}")
    from observer_gym.estimation.learned.frame_detector import save_detector
    from observer_gym.estimation.learned.frame_training import fit_detector

    tic = time.perf_counter()
    try:
        data = _frames(collect_frames, env_id, episodes, args.seed, args.cache)
    except ValueError as exc:
        return _fail(str(exc))
    collect_s = time.perf_counter() - tic
    if hasattr(system, "fit"):  # a network of the system's own
        net, report = system.fit(data, args.seed, epochs)
    else:
        net, report = fit_detector(data, system.VALUE_PARTS, args.seed, epochs)
    words = [PROG, "--env", env_id]
    if args.episodes is not None and episodes != system.EPISODES:
        words += ["--episodes", str(episodes)]
    if args.seed != 0:
        words += ["--seed", str(args.seed)]
    if epochs != default_epochs:
        words += ["--epochs", str(epochs)]
    if args.out is not None:
        words += ["--out", str(args.out)]
    report = {
        "command": " ".join(words),
        "env": env_id,
        "episodes": episodes,
        "frames": len(data.frames),
        "camera_px": list(system.CAMERA_PX),
        "training_ranges": system.FRAME_RANGES,
        **report,
        "collect_s": round(collect_s, 1),
        "total_s": round(time.perf_counter() - tic, 1),
    }
    if hasattr(system, "save"):
        system.save(net, out, report)
    else:
        save_detector(net, system.CAMERA_PX, out, report)
    held = report["held_out"]
    print(
        f"{out}: {report['frames']} frames, held-out NEES/dof {held.get('nees_per_dof', 'n/a')}, "
        f"RMSE {', '.join(f'{v:.2f}' for v in held.get('rmse_px', []))} px; "
        f"{report['total_s']} s"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
