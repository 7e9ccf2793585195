"""The shape ``--video DIR`` and ``--rerun`` share: an option naming where chosen
episodes' files go, an option choosing the episodes, and the experiments' two keyword
arguments they become (:mod:`observer_gym.train.cli.video_options`,
:mod:`observer_gym.train.cli.rerun_options`)."""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Callable
from typing import Any


@dataclasses.dataclass(frozen=True)
class EpisodeFilesOption:
    """``flag TARGET`` and ``episodes_flag``: ``keys`` are the experiments' keyword
    arguments for the target and the chosen episodes; ``require`` raises
    :class:`~observer_gym.extras.ExtraNotInstalled` when the extra that writes the files
    is missing."""

    flag: str
    metavar: str
    episodes_flag: str
    keys: tuple[str, str]
    require: Callable[[], None]

    def add_to(
        self,
        parser: argparse.ArgumentParser,
        help: str,
        episodes_help: str,
        episodes_type: Callable[[str], Any],
        episodes_metavar: str,
        type: Callable[[str], Any] | None = None,
    ) -> None:
        """Add both options to ``parser``."""
        parser.add_argument(
            self.flag, type=type or str, default=None, metavar=self.metavar, help=help
        )
        parser.add_argument(
            self.episodes_flag,
            type=episodes_type,
            default=None,
            metavar=episodes_metavar,
            help=episodes_help,
        )

    def options(self, args: argparse.Namespace) -> dict[str, Any]:
        """The experiments' keyword arguments from the parsed options, {} without
        ``flag``; refuses a missing extra first (one line and exit code 2 from
        :func:`observer_gym.train.cli.main`), and ``episodes_flag`` without ``flag``
        (ValueError)."""
        target = getattr(args, _dest(self.flag))
        chosen = getattr(args, _dest(self.episodes_flag))
        if target is None:
            if chosen is not None:
                raise ValueError(f"{self.episodes_flag} needs {self.flag} {self.metavar}")
            return {}
        self.require()
        return {self.keys[0]: target, self.keys[1]: chosen}


def _dest(flag: str) -> str:
    return flag.lstrip("-").replace("-", "_")
