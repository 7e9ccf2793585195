"""``observer-gym reproduce``: re-run a source paper's study."""

from __future__ import annotations

import argparse
import importlib
import importlib.util
from collections.abc import Callable

from observer_gym.train.cli.args import Command


def _study_runner(module_name: str) -> Callable[[argparse.Namespace], int]:
    """The ``run`` of the study module ``module_name``, imported when called."""

    def run(args: argparse.Namespace) -> int:
        return importlib.import_module(module_name).run(args)

    return run


def _reproduce_arguments(parser: argparse.ArgumentParser) -> None:
    from observer_gym.train.experiments.reproduce import STUDIES
    from observer_gym.train.experiments.reproduce.arguments import ARGUMENTS

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


COMMAND = Command(
    help="re-run a source paper's study and print its figures beside the paper's",
    description=(
        "Re-run the study of one of the source papers in spec/ (linderoth2010: the "
        "viewline Kalman filter's convergence; tsai2009: the self-tuning Kalman filter's "
        "Table 2) and print the measured figures beside the paper's; plots are saved "
        "into the output folder."
    ),
    add_arguments=_reproduce_arguments,
    run=_reproduce_run,
)
