"""``--video DIR`` and ``--video-episodes``: the options every command that runs episodes
takes (``run``, ``compare``, ``sweep``, ``evaluate``, ``benchmark``), and what they pass
to the experiments (:mod:`observer_gym.train.experiments.videos`)."""

from __future__ import annotations

import argparse
from typing import Any

from observer_gym.extras import require_video
from observer_gym.train.cli.episode_files import EpisodeFilesOption
from observer_gym.train.core.args import folder_path, seed_list

VIDEO = EpisodeFilesOption(
    "--video", "DIR", "--video-episodes", ("video_dir", "video_episodes"), require_video
)


def add_video_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--video DIR`` and ``--video-episodes I,J``."""
    VIDEO.add_to(
        parser,
        help=(
            "write an MP4 of the chosen episodes into DIR (one per camera): the camera "
            "images the observer received with its detection, the estimate and its 2-sigma "
            "ellipse, the truth and each frame's age, beside the error and the action; "
            "observers that read images only (needs pip install 'observer-gym[video]'; "
            "docs/watch.md)"
        ),
        type=folder_path,
        episodes_help="which episodes --video films, indices from 0 and ranges A-B (default: 0)",
        episodes_type=seed_list,
        episodes_metavar="I,J",
    )


def video_options(args: argparse.Namespace) -> dict[str, Any]:
    """The experiments' ``video_dir`` and ``video_episodes`` from the parsed options;
    refuses a missing ``[video]`` extra first
    (:class:`~observer_gym.extras.ExtraNotInstalled`, one line and exit code 2 from
    :func:`observer_gym.train.cli.main`), and ``--video-episodes`` without ``--video``
    (ValueError)."""
    return VIDEO.options(args)
