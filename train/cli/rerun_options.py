"""``--rerun FILE.rrd`` and ``--rerun-episode``: the options of ``run`` that write one
episode's recording for the rerun viewer, and what they pass to the experiments
(:func:`observer_gym.train.experiments.videos.plan_rerun`)."""

from __future__ import annotations

import argparse
from typing import Any

from observer_gym.train.core.args import nonnegative_int


def add_rerun_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--rerun FILE.rrd`` and ``--rerun-episode I``."""
    parser.add_argument(
        "--rerun",
        default=None,
        metavar="FILE.rrd",
        help=(
            "write a recording of one episode into FILE.rrd to scrub in the rerun viewer: "
            "the ball's truth and estimate with its 2-sigma ellipsoid in 3-D, the scene's "
            "boxes, each camera's nominal and true frustum, the images with the video's "
            "overlays, the error, NEES and action over the simulation time (needs pip "
            "install 'observer-gym[rerun]'; docs/watch.md)"
        ),
    )
    parser.add_argument(
        "--rerun-episode",
        type=nonnegative_int,
        default=None,
        metavar="I",
        help="which episode --rerun records, an index from 0 (default: 0)",
    )


def rerun_options(args: argparse.Namespace) -> dict[str, Any]:
    """The experiments' ``rerun_file`` and ``rerun_episode`` from the parsed options;
    refuses a missing ``[rerun]`` extra first
    (:class:`~observer_gym.extras.ExtraNotInstalled`, one line and exit code 2 from
    :func:`observer_gym.train.cli.main`), and ``--rerun-episode`` without ``--rerun``
    (ValueError)."""
    if args.rerun is None:
        if args.rerun_episode is not None:
            raise ValueError("--rerun-episode needs --rerun FILE.rrd")
        return {}
    from observer_gym.extras import require_rerun

    require_rerun()
    return {"rerun_file": args.rerun, "rerun_episode": args.rerun_episode}
