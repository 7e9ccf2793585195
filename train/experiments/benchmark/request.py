"""A checked ``observer-gym benchmark`` request, and the command line that computes its
numbers again: what the runner (run.py) and the outputs (report.py) share."""

from __future__ import annotations

import shlex
from collections.abc import Mapping
from typing import Any, NamedTuple

from observer_gym.envs import system_for_id
from observer_gym.train.core.observer_env import observer_env_options, resolve_observer
from observer_gym.train.experiments.benchmark.levels import plan_digest
from observer_gym.train.experiments.benchmark.suite import DEFAULT_VERSION, Level, SystemSuite
from observer_gym.train.experiments.camera_scale import options_in_entry_pixels
from observer_gym.train.experiments.episode import EpisodeSpec, entry_identities
from observer_gym.train.experiments.request import resolve_controller

__all__ = ["BenchmarkRequest", "command_line"]


def command_line(
    suite: SystemSuite, observer: str, controller: str, episodes: int,
    observer_options: Mapping[str, Any], controller_options: Mapping[str, Any],
) -> str:  # fmt: skip
    """The ``observer-gym benchmark`` command that computes a run's numbers again (add
    ``--out DIR``; workers and backend do not change them)."""
    words = ["observer-gym", "benchmark", "--env", suite.system.short_id,
             "--observer", observer, "--controller", controller]  # fmt: skip
    for kind, options in (("observer", observer_options), ("controller", controller_options)):
        for key, value in options.items():
            words += [
                f"--{kind}-option",
                f"{key}={value!r}" if isinstance(value, str) else f"{key}={value}",
            ]
    if suite.version != DEFAULT_VERSION:
        words += ["--suite", suite.version]
    if episodes != suite.episodes:
        words += ["--episodes", str(episodes)]
    return " ".join(shlex.quote(word) for word in words)


class BenchmarkRequest(NamedTuple):
    """A checked ``benchmark`` request."""

    suite: SystemSuite
    observer: str
    controller: str
    episodes: int  # per level
    workers: int
    backend: str
    address: str | None
    observer_options: dict[str, Any]
    controller_options: dict[str, Any]
    # a trained agent's env options (its config's env_kwargs: image size, reward
    # shaping), under every level's options; empty for any other controller
    agent_env_options: dict[str, Any]
    # the agent's camera's focal length over the default camera's (camera_scale.py): the
    # levels' pixel-valued options are scaled by it (a metric in pixels is the default
    # camera's already: the task's)
    camera_scale: float = 1.0

    @property
    def observer_env_options(self) -> dict[str, Any]:
        """The env options the observer needs (set by make_env wherever it runs; e.g.
        BallCatcher's ``endpoint-measurements``: ``hole_measurements``), recorded."""
        return observer_env_options(system_for_id(self.suite.env_id), self.observer)

    @property
    def official(self) -> bool:
        """Whether the run uses the suite's full episode count on every level."""
        return self.episodes == self.suite.episodes

    def identity(self) -> dict[str, Any]:
        """What decides the run's numbers (``benchmark.json`` holds it; JSON types)."""
        return {
            "suite": self.suite.version,
            "env": self.suite.env_id,
            "observer": self.observer,
            "controller": self.controller,
            "observer_options": self.observer_options,
            "controller_options": self.controller_options,
            "episodes": self.episodes,
            "official": self.official,
            "levels": {level.name: level.env_options for level in self.suite.levels},
            # only when there are some: folders of other entries keep their identity
            **({"agent_env_options": self.agent_env_options} if self.agent_env_options else {}),
            **({"camera_scale": self.camera_scale} if self.camera_scale != 1.0 else {}),
            **(
                {"observer_env_options": self.observer_env_options}
                if self.observer_env_options
                else {}
            ),
            # where outside entries come from: an upgraded package's levels are not reused
            **({"entries": self.entries} if self.entries else {}),
        }

    @property
    def entries(self) -> dict[str, dict[str, Any]]:
        """Where an outside observer and controller come from
        (:func:`~observer_gym.train.experiments.episode.entry_identities`); {} for the
        package's own."""
        system = system_for_id(self.suite.env_id)
        return entry_identities(
            resolve_observer(system, self.observer),
            resolve_controller(system, self.controller),
        )

    def digest(self) -> str:
        return plan_digest(self.identity())

    def specs(self, level: Level) -> list[EpisodeSpec]:
        """The level's episodes, the system and entries resolved once for them."""
        system = system_for_id(self.suite.env_id)
        observer = resolve_observer(system, self.observer, self.observer_options)
        controller = resolve_controller(system, self.controller, self.controller_options)
        return [
            EpisodeSpec.of_entries(
                system,
                observer,
                controller,
                seed,
                # the level's sensor options (in the agent camera's pixels) win over the
                # agent's own
                env_kwargs={
                    **self.agent_env_options,
                    **options_in_entry_pixels(level.env_options, self.camera_scale),
                },
            )
            for seed in level.seeds(self.episodes)
        ]

    def command(self) -> str:
        """The command line that computes these numbers again (add ``--out DIR``)."""
        return command_line(
            self.suite, self.observer, self.controller, self.episodes,
            self.observer_options, self.controller_options,
        )  # fmt: skip
