"""``--video DIR`` and ``--rerun`` for the experiments: which episodes get a video
or a rerun recording, checked before any runs.

:func:`plan_videos` checks a request for videos once, up front (the ``[video]`` extra
installed, every observer reading camera images, the episode indices within the run, the
folder writable) and :func:`with_videos` marks the chosen episodes' specs, so that
:func:`~observer_gym.train.experiments.episode.run_episode` writes their videos as they
run (:mod:`observer_gym.train.reports.video`), in whichever process runs them;
:func:`plan_rerun` and :func:`with_rerun` do the same for one episode's rerun recording
(``run``'s ``--rerun FILE.rrd``; :mod:`observer_gym.train.reports.rerun_recording`), and
:func:`plan_reruns` and :func:`with_reruns` for a folder of them, one per chosen episode of
each pair, cell or level (``--rerun DIR``), named as the videos are.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from pathlib import Path

from observer_gym.envs import system_for_id
from observer_gym.extras import require_rerun, require_video
from observer_gym.train.core.observer_env import ObserverEntry, resolve_observer
from observer_gym.train.experiments.episode import EpisodeSpec
from observer_gym.train.reports.rerun_recording import (
    RerunRequest,
    check_rerun_file,
    check_rerun_folder,
)
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
    folder = str(plan.folder)
    return _marked(
        specs,
        episodes,
        prefix,
        lambda spec, episode: episode in plan.episodes and spec.observer.name in plan.observers,
        lambda spec, stem: dataclasses.replace(spec, video=VideoRequest(folder, stem)),
    )


def _marked(
    specs: Sequence[EpisodeSpec],
    episodes: int,
    prefix: str,
    chosen: Callable[[EpisodeSpec, int], bool],
    mark: Callable[[EpisodeSpec, str], EpisodeSpec],
) -> list[EpisodeSpec]:
    """``specs`` (groups of ``episodes``) with ``mark(spec, stem)`` on the episodes
    ``chosen(spec, index in the group)`` picks; the stem ``prefix`` +
    :func:`~observer_gym.train.reports.video.video_stem`."""
    marked = []
    for k, spec in enumerate(specs):
        episode = k % episodes
        if chosen(spec, episode):
            stem = prefix + video_stem(
                spec.env_id, spec.observer.name, spec.controller.name, episode, spec.seed
            )
            spec = mark(spec, stem)
        marked.append(spec)
    return marked


@dataclasses.dataclass(frozen=True)
class RerunPlan:
    """The ``.rrd`` file and the episode recorded into it (its index in the run)."""

    path: Path
    episode: int


def plan_rerun(
    rerun_file: str | Path | None, rerun_episode: int | None, episodes: int
) -> RerunPlan | None:
    """The checked plan of a rerun recording, None without ``rerun_file``. Raises, before
    anything runs: :class:`~observer_gym.extras.ExtraNotInstalled` without the
    ``[rerun]`` extra, ValueError for a file not ending in ``.rrd`` or an episode index
    outside 0..episodes-1 (or given without a file),
    :class:`~observer_gym.train.core.atomic_write.WriteError` for a folder that cannot be
    written."""
    if rerun_file is None:
        if rerun_episode is not None:
            raise ValueError("a rerun episode was given without a rerun file (--rerun FILE.rrd)")
        return None
    require_rerun()
    episode = 0 if rerun_episode is None else int(rerun_episode)
    if not 0 <= episode < episodes:
        raise ValueError(
            f"rerun episode {episode} is outside the run's episodes 0..{episodes - 1} "
            "(indices from 0: episode i resets with seed + i)"
        )
    return RerunPlan(check_rerun_file(rerun_file), episode)


def with_rerun(specs: Sequence[EpisodeSpec], plan: RerunPlan | None) -> list[EpisodeSpec]:
    """``specs`` (one per episode of a run) with a
    :class:`~observer_gym.train.reports.rerun_recording.RerunRequest` on the planned one."""
    if plan is None:
        return list(specs)
    path = str(plan.path)
    return _marked(
        specs,
        len(specs),
        "",
        lambda spec, episode: episode == plan.episode,
        lambda spec, name: dataclasses.replace(spec, rerun=RerunRequest(path, name)),
    )


@dataclasses.dataclass(frozen=True)
class RerunFolderPlan:
    """The folder the rerun recordings go to (one ``.rrd`` per recorded episode, named as
    the videos are) and the episodes recorded of each pair, cell or level (indices in its
    run)."""

    folder: Path
    episodes: tuple[int, ...]


def plan_reruns(
    rerun_dir: str | Path | None, rerun_episodes: Sequence[int] | None, episodes: int
) -> RerunFolderPlan | None:
    """The checked plan of ``--rerun DIR`` (compare, sweep, benchmark), None without
    ``rerun_dir``. Raises, before anything runs:
    :class:`~observer_gym.extras.ExtraNotInstalled` without the ``[rerun]`` extra,
    ValueError for an episode index outside 0..episodes-1 (or indices given without a
    folder) and a folder named ``*.rrd``,
    :class:`~observer_gym.train.core.atomic_write.WriteError` for a folder that cannot be
    written."""
    if rerun_dir is None:
        if rerun_episodes is not None:
            raise ValueError("rerun episodes were given without a rerun folder (--rerun DIR)")
        return None
    require_rerun()
    chosen = chosen_episodes(rerun_episodes, episodes, what="rerun")
    return RerunFolderPlan(check_rerun_folder(rerun_dir), chosen)


def with_reruns(
    specs: Sequence[EpisodeSpec], plan: RerunFolderPlan | None, episodes: int, prefix: str = ""
) -> list[EpisodeSpec]:
    """``specs`` (groups of ``episodes`` consecutive episodes, one group per pair, cell or
    level) with a :class:`~observer_gym.train.reports.rerun_recording.RerunRequest` on
    the chosen episodes of each group: ``folder/<prefix><stem>.rrd``, the stem the video
    of the same episode gets (:func:`with_videos`)."""
    if plan is None:
        return list(specs)
    return _marked(
        specs,
        episodes,
        prefix,
        lambda spec, episode: episode in plan.episodes,
        lambda spec, stem: dataclasses.replace(
            spec, rerun=RerunRequest(str(plan.folder / f"{stem}.rrd"), stem)
        ),
    )
