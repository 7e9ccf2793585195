"""``--rerun``: the options that write episodes' recordings for the rerun viewer, and what
they pass to the experiments (:mod:`observer_gym.train.experiments.videos`).

``run`` and ``evaluate`` run one pair: ``--rerun FILE.rrd`` with ``--rerun-episode I``
records one episode into one file. ``compare``, ``sweep`` and ``benchmark`` run many
pairs, cells or levels: ``--rerun DIR`` with ``--rerun-episodes I,J`` writes one ``.rrd``
per chosen episode of each, named as ``--video`` names its files."""

from __future__ import annotations

import argparse
from typing import Any

from observer_gym.extras import require_rerun
from observer_gym.train.cli.episode_files import EpisodeFilesOption
from observer_gym.train.core.args import folder_path, nonnegative_int, seed_list

RERUN_FILE = EpisodeFilesOption(
    "--rerun", "FILE.rrd", "--rerun-episode", ("rerun_file", "rerun_episode"), require_rerun
)
RERUN_DIR = EpisodeFilesOption(
    "--rerun", "DIR", "--rerun-episodes", ("rerun_dir", "rerun_episodes"), require_rerun
)
WHAT = (
    "the ball's truth and estimate with its 2-sigma ellipsoid in 3-D, the scene's boxes, "
    "each camera's nominal and true frustum, the images with the video's overlays, the "
    "error, NEES and action over the simulation time (needs pip install "
    "'observer-gym[rerun]'; docs/watch.md)"
)


def add_rerun_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--rerun FILE.rrd`` and ``--rerun-episode I`` (one pair's run)."""
    RERUN_FILE.add_to(
        parser,
        help=f"write a recording of one episode into FILE.rrd to scrub in the rerun viewer: {WHAT}",
        episodes_help="which episode --rerun records, an index from 0 (default: 0)",
        episodes_type=nonnegative_int,
        episodes_metavar="I",
    )


def add_rerun_folder_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--rerun DIR`` and ``--rerun-episodes I,J`` (many pairs, cells or levels)."""
    RERUN_DIR.add_to(
        parser,
        help=(
            "write a recording of each chosen episode of every pair (cell, level) into DIR, "
            f"one .rrd each named as --video names its files, to scrub in the rerun viewer: {WHAT}"
        ),
        type=folder_path,
        episodes_help="which episodes --rerun records, indices from 0 and ranges A-B (default: 0)",
        episodes_type=seed_list,
        episodes_metavar="I,J",
    )


def rerun_options(args: argparse.Namespace) -> dict[str, Any]:
    """The experiments' ``rerun_file`` and ``rerun_episode`` from ``--rerun FILE.rrd``;
    refuses a missing ``[rerun]`` extra first
    (:class:`~observer_gym.extras.ExtraNotInstalled`, one line and exit code 2 from
    :func:`observer_gym.train.cli.main`), and ``--rerun-episode`` without ``--rerun``
    (ValueError)."""
    return RERUN_FILE.options(args)


def rerun_folder_options(args: argparse.Namespace) -> dict[str, Any]:
    """The experiments' ``rerun_dir`` and ``rerun_episodes`` from ``--rerun DIR``, refused
    as :func:`rerun_options` refuses."""
    return RERUN_DIR.options(args)
