"""``observer-gym reproduce NAME``: re-run a source paper's study and print its figures
beside the paper's.

Each entry of :data:`STUDIES` names a module of this package with ``DESCRIPTION`` (one
line), ``add_arguments(parser)`` and ``run(args) -> int`` (the process exit code). The
description and options live in :mod:`observer_gym.train.experiments.reproduce.arguments` (same
names), so the command line is parsed without importing a study.
"""

from __future__ import annotations

# study name -> module in observer_gym.train.experiments.reproduce
STUDIES: dict[str, str] = {
    "linderoth2010": "observer_gym.train.experiments.reproduce.linderoth2010",
    "tsai2009": "observer_gym.train.experiments.reproduce.tsai2009",
}
