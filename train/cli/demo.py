"""``observer-gym demo``: centre the ball on BallTable-v0 from camera frames (the pixel observer
and the LQR)."""

from __future__ import annotations

import argparse

from observer_gym.train.cli.args import Command, add_output_arguments, command_error
from observer_gym.train.core.args import positive_float, positive_int


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


def _demo_run(args: argparse.Namespace) -> int:
    from observer_gym.train.reports.outputs import (
        OutputFolderError,
        check_folder_kind,
        default_out_dir,
    )

    out_dir = args.out if args.out is not None else default_out_dir("demo")
    try:
        check_folder_kind(out_dir, "demo")  # another command's results: refused up front
    except OutputFolderError as exc:
        return command_error("demo", exc)
    from observer_gym.train.experiments import demo  # deferred: imports PyBullet and OpenCV

    print(demo.INTRODUCTION)
    try:
        summary = demo.run_demo(
            out_dir=out_dir,
            seconds=args.seconds,
            seed=args.seed,
            frame_every=args.frame_every,
            progress=not args.no_progress,
        )
    except OutputFolderError as exc:  # filled by another command since the check above
        return command_error("demo", exc)
    print(demo.summary_text(summary))
    print(f"output: {out_dir}")
    return 0


COMMAND = Command(
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
)
