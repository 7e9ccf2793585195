"""``--video DIR`` for the experiments: which episodes get a video, checked before any runs.

:func:`plan_videos` checks a request for videos once, up front (the ``[video]`` extra
installed, every observer reading camera images, the episode indices within the run, the
folder writable) and :func:`with_videos` marks the chosen episodes' specs, so that
:func:`~observer_gym.train.experiments.episode.run_episode` writes their videos as they
run (:mod:`observer_gym.train.reports.video`), in whichever process runs them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

from observer_gym.envs import system_for_id
from observer_gym.extras import require_video
from observer_gym.train.core.observer_env import ObserverEntry, resolve_observer
from observer_gym.train.experiments.episode import EpisodeSpec
from observer_gym.train.reports.video import (
    VideoRequest,
    check_video_folder,
    check_video_observer,
    chosen_episodes,
    video_stem,
)


@dataclasses.dataclass(frozen=True)
class VideoPlan:
    """The folder the videos go to, the episodes filmed (indices in the run: episode i
    resets with the run's i-th seed) and the observers filmed (those that read camera
    images)."""

    folder: Path
    episodes: tuple[int, ...]
    observers: frozenset[str]


def plan_videos(
    video_dir: str | Path | None,
    video_episodes: Sequence[int] | None,
    episodes: int,
    env_id: str,
    observers: Sequence[str],
) -> VideoPlan | None:
    """The checked plan, None without ``video_dir``, for observers by name (the command
    line's: each resolved once, then :func:`plan_videos_for`)."""
    if video_dir is None:
        return plan_videos_for(None, video_episodes, episodes, [])
    system = system_for_id(env_id)
    entries = [resolve_observer(system, observer) for observer in observers]
    return plan_videos_for(video_dir, video_episodes, episodes, entries)


def plan_videos_for(
    video_dir: str | Path | None,
    video_episodes: Sequence[int] | None,
    episodes: int,
    observers: Sequence[ObserverEntry],
) -> VideoPlan | None:
    """The checked plan, None without ``video_dir``. Of several observers (compare,
    sweep) those that read camera images are filmed. Raises, before anything runs:
    :class:`~observer_gym.extras.ExtraNotInstalled` without the ``[video]`` extra,
    ValueError when no observer reads images or for an episode index outside
    0..episodes-1, :class:`~observer_gym.train.core.atomic_write.WriteError` for a folder
    that cannot be written."""
    if video_dir is None:
        if video_episodes is not None:
            raise ValueError("video episodes were given without a video folder (--video DIR)")
        return None
    require_video()
    modes = {observer.name: observer.obs_mode for observer in observers}
    filmed = frozenset(o for o, mode in modes.items() if mode == "rgb")
    if not filmed:
        first = next(iter(modes))
        check_video_observer(modes[first], first)  # raises: it names the choice
    chosen = chosen_episodes(video_episodes, episodes)
    return VideoPlan(check_video_folder(video_dir), chosen, filmed)


def with_videos(
    specs: Sequence[EpisodeSpec], plan: VideoPlan | None, episodes: int, prefix: str = ""
) -> list[EpisodeSpec]:
    """``specs`` (groups of ``episodes`` consecutive episodes, one group per pair or cell)
    with a :class:`~observer_gym.train.reports.video.VideoRequest` on the chosen episodes
    of each group whose observer is filmed; ``prefix`` begins the file names (a sweep's
    cell)."""
    if plan is None:
        return list(specs)
    marked = []
    for k, spec in enumerate(specs):
        episode = k % episodes
        if episode in plan.episodes and spec.observer.name in plan.observers:
            stem = prefix + video_stem(
                spec.env_id, spec.observer.name, spec.controller.name, episode, spec.seed
            )
            spec = dataclasses.replace(spec, video=VideoRequest(str(plan.folder), stem))
        marked.append(spec)
    return marked
