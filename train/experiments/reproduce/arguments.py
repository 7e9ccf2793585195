"""The command line of each study of ``observer-gym reproduce``: its one-line
description and its options, kept apart from the studies (which import the estimation
and controller layers) so that parsing a command line imports no study.

:data:`ARGUMENTS` has an entry for each name of
:data:`observer_gym.train.experiments.reproduce.STUDIES`;
each study module exposes its entry as ``DESCRIPTION`` and ``add_arguments``.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

from observer_gym.train.core.args import int_at_least, nonnegative_int, positive_float, positive_int


class StudyArguments(NamedTuple):
    """A study's one-line description and the function that adds its options."""

    description: str
    add_arguments: Callable[[argparse.ArgumentParser], None]


def _nonnegative_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"must be a number >= 0, got {text}")
    return value


def _finite_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text}")
    return value


# --- linderoth2010 ---------------------------------------------------------------------
def _linderoth2010(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        metavar="DIR",
        help="output folder for results.json, two_cameras_ellipses.png and "
        "single_camera_ellipses.png (default: "
        "observer-gym-out/reproduce-linderoth2010-YYYYmmdd-HHMMSS-PID)",
    )
    parser.add_argument(
        "--seed", type=nonnegative_int, default=0, help="seed of throws and noise (default: 0)"
    )
    parser.add_argument(
        "--pixel-std",
        type=positive_float,
        default=0.5,
        metavar="PX",
        help="pixel noise std in px (default: 0.5)",
    )
    parser.add_argument(
        "--runs",
        type=positive_int,
        default=40,
        help="throws in the two-camera runs (default: 40)",
    )
    parser.add_argument(
        "--single-runs",
        type=positive_int,
        default=10,
        metavar="RUNS",
        help="throws in the single-camera run, each from 8 inits (default: 10)",
    )


LINDEROTH2010 = StudyArguments(
    "viewline Kalman filter (Linderoth et al. 2010): two alternating cameras and one static "
    "camera on synthetic throws, figures beside the paper's, covariance-ellipse plots",
    _linderoth2010,
)


# --- tsai2009 --------------------------------------------------------------------------
TSAI2009_DEFAULT_RUNS = 20
TSAI2009_DEFAULT_STEPS = 400
TSAI2009_DEFAULT_WINDOW = 10


def _tsai2009(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--runs",
        type=positive_int,
        default=TSAI2009_DEFAULT_RUNS,
        help="runs per sigma_n and filter (default: 20)",
    )
    parser.add_argument(
        "--steps",
        type=int_at_least(10),
        default=TSAI2009_DEFAULT_STEPS,
        help="samples per run, >= 10 (default: 400 = 40 s)",
    )
    parser.add_argument(
        "--sigmas",
        type=_nonnegative_float,
        nargs="+",
        default=list(range(11)),
        metavar="S",
        help="noise levels sigma_n in px (default: 0 1 ... 10)",
    )
    parser.add_argument(
        "--window",
        type=int_at_least(3),
        default=TSAI2009_DEFAULT_WINDOW,
        help="STKF register length k, >= 3 (default: 10)",
    )
    parser.add_argument(
        "--seed", type=nonnegative_int, default=0, help="run r resets with seed + r (default: 0)"
    )
    parser.add_argument(
        "--turn-rate-radps",
        type=_finite_float,
        default=None,
        metavar="W",
        help="the target's turn rate in (44) (default: 5 pi / 72 = 0.218; 0: no turning, "
        "which isolates what the turning costs the filters)",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        metavar="DIR",
        help="output folder for results.json and fig8_mse_vs_noise.png (default: "
        "observer-gym-out/reproduce-tsai2009-YYYYmmdd-HHMMSS-PID)",
    )


TSAI2009 = StudyArguments(
    "self-tuning Kalman filter (Tsai et al. 2009): Table 2's MSE of KF and STKF over "
    "sigma_n = 0..10 in closed loop with the VTC, beside the paper's, and Fig. 8's plot",
    _tsai2009,
)

ARGUMENTS: dict[str, StudyArguments] = {"linderoth2010": LINDEROTH2010, "tsai2009": TSAI2009}
