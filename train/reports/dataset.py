"""Episodes kept as a Minari dataset (``observer-gym record``), and read back.

Writing goes through Minari's own :class:`minari.DataCollector` around the observer env
(:func:`recording_env`): the observations of the env's obs mode (camera frames,
measurements or the state, stored losslessly: no JPEG) rather than the estimate the
observer makes of them, the actions, rewards, terminations and truncations; and in the
infos, per step, the fixed arrays of :func:`step_info`: the ground-truth state, the newest
delivered frame's capture and delivery times and calibration per camera (from
:func:`~observer_gym.train.reports.episode_frames.delivered_frames`), and the observer's
estimate and covariance. Minari keeps infos only if every step's have the same keys,
types and shapes; the env's own info does not (a step delivers 0, 1 or more frames), so
it is flattened to one row per camera, NaN where a camera delivered nothing.

A dataset is written into a staging folder beside the output folder
(``.NAME.tmp-PID``, removed on failure, and by the next recording into the same folder
if the run was killed: :func:`remove_killed_stagings`), with
``MINARI_DATASETS_PATH`` pointing there while Minari writes, and renamed to the output
folder at the end: a folder named like the output is a whole dataset. The staging is by
hand because Minari writes a folder tree, not a file (``replace_atomically`` and
``output_set`` move files into an existing folder).

Needs the ``[record]`` extra (``minari[create,hdf5]``): import this module after
:func:`observer_gym.extras.require_record`.
"""

from __future__ import annotations

import dataclasses
import glob
import os
import re
import shutil
import warnings
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import gymnasium as gym
import minari
import numpy as np
from minari.data_collector.callbacks import StepDataCallback

from observer_gym.envs import System
from observer_gym.envs.json_file import read_json
from observer_gym.train.core.observer_env import (
    ObserverEntry,
    check_gym_make_options,
    with_observer_env_options,
    wrap_observer,
)
from observer_gym.train.core.signals import signals_deferred
from observer_gym.train.reports.episode_frames import delivered_frames
from observer_gym.train.reports.outputs import OutputFolderWarning, process_alive

# every dataset observer-gym records is in this Minari namespace
NAMESPACE = "observer_gym"
# the file beside the dataset naming it and what was recorded (record.json)
RECORD_FILE = "record.json"
# DataCollector.reset's option that, False, keeps it from seeding a reset given no seed
# (the world's seed is then drawn beneath it, as the episode's options are)
MINARI_AUTOSEED = "minari_autoseed"
# an episode's metadata key of the options drawn for it (randomised recordings)
DRAWN_OPTIONS = "drawn_options"


def dataset_id_for(system: str, observer: str, controller: str) -> str:
    """The Minari dataset id of a recording, ``observer_gym/SYSTEM-OBSERVER-CONTROLLER-v0``
    (``observer_gym/ball_table-kf-lqr-v0``); characters a Minari id does not take (the
    ``:`` and ``/`` of ``ppo:runs/x``) become ``_``."""
    name = re.sub(r"[^A-Za-z0-9_-]", "_", f"{system}-{observer}-{controller}")
    return f"{NAMESPACE}/{name}-v0"


def step_info(env: gym.Env, info: Mapping[str, Any]) -> dict[str, np.ndarray]:
    """One step's (or the reset's) ``info`` as fixed arrays, the same keys and shapes at
    every step of an env (what Minari keeps); C is the env's number of cameras, n the
    state's size:

    - ``time_s`` (): the env's time since the reset, s;
    - ``state`` (n,): the ground truth, the env's state layout (SI units);
    - ``frame_count`` (C,): frames of each camera delivered at this step;
    - ``frames_lost`` (C,): frames of each camera dropped at capture since the reset (the
      sensor's ``frame_drop_prob``; the truth, which the observer sees only as gaps in
      the capture times): a step's drops are its difference from the step before;
    - ``frame_capture_time_s``, ``frame_delivery_time_s`` (C,): the newest delivered
      frame's capture and delivery times, s since the reset; NaN for a camera without one;
    - ``K_nominal``, ``K_true`` (C, 3, 3), px: that frame's intrinsics as the observer was
      told and as the world's camera was; ``T_world_cam_nominal``, ``T_world_cam_true``
      (C, 4, 4), m: its camera pose in the world; NaN without a frame;
    - with an observer's estimate (not for ``oracle`` or ``pixels``): ``estimate_mean``
      (n,), ``estimate_covariance`` (n, n) and ``estimate_nis`` () (NaN when the step's
      update has none);
    - where the env's info has them (BallTable, TargetFollower): ``applied_action``
      (m,), the last action as the env applied it (``info["applied_action"]``; NaN
      before the first), and ``camera_T_world_cam`` (4, 4), m: the camera's nominal pose
      in the world now (``info["camera"]["T_world_cam"]``), which TargetFollower's
      learned observer's features read;
    - BallCatcher: ``ball_in_flight`` () (``info["ball_in_flight"]``: before the ball's
      first touch of the box) and, in the measurements obs mode, ``frame_uv_px`` (C, 2),
      px: the newest delivered frame's ball pixel as the frame reports it
      (``info["frames"][i]["uv_px"]``, float64), NaN without a detection or a frame;
      ``frame_earlier_uv_px`` (C, 2), px, and ``frame_earlier_capture_time_s`` (C,), s:
      the frame of the camera delivered before its newest in the same step (latency
      jitter can deliver two), NaN if none (a third one is counted in ``frame_count``
      only).
    """
    cameras = int(env.unwrapped.rig.num_cameras)  # type: ignore[attr-defined]
    row: dict[str, np.ndarray] = {
        "time_s": np.asarray(float(info["time_s"])),
        "state": np.array(info["state"], dtype=np.float64),
        "frame_count": np.zeros(cameras, dtype=np.int64),
        "frames_lost": np.array(env.unwrapped.rig.frames_lost(), dtype=np.int64),  # type: ignore[attr-defined]
        "frame_capture_time_s": np.full(cameras, np.nan),
        "frame_delivery_time_s": np.full(cameras, np.nan),
        "K_nominal": np.full((cameras, 3, 3), np.nan),
        "K_true": np.full((cameras, 3, 3), np.nan),
        "T_world_cam_nominal": np.full((cameras, 4, 4), np.nan),
        "T_world_cam_true": np.full((cameras, 4, 4), np.nan),
    }
    # in delivery order: the last of a camera's frames is its newest
    for frame in delivered_frames(env, info, 0):
        c = frame.camera_id
        row["frame_count"][c] += 1
        row["frame_capture_time_s"][c] = frame.capture_time_s
        row["frame_delivery_time_s"][c] = frame.delivery_time_s
        row["K_nominal"][c], row["K_true"][c] = frame.K, frame.K_true
        row["T_world_cam_nominal"][c] = frame.T_world_cam
        row["T_world_cam_true"][c] = frame.T_world_cam_true
    base: Any = env.unwrapped
    if base.config.obs_mode == "measurements" and "uv_px" in getattr(
        base.observation_space, "spaces", {}
    ):  # each delivered frame's own measurement (BallCatcher), float64 as the info has it
        row["frame_uv_px"] = np.full((cameras, 2), np.nan)
        row["frame_earlier_uv_px"] = np.full((cameras, 2), np.nan)
        row["frame_earlier_capture_time_s"] = np.full(cameras, np.nan)
        capture_s = np.full(cameras, np.nan)
        for frame in info["frames"]:  # in delivery order: the last of a camera's wins
            c = int(frame["camera_id"])
            if not np.isnan(capture_s[c]):  # a second frame of the camera in this step
                row["frame_earlier_uv_px"][c] = row["frame_uv_px"][c]
                row["frame_earlier_capture_time_s"][c] = capture_s[c]
            uv = frame.get("uv_px")
            row["frame_uv_px"][c] = np.nan if uv is None else uv
            capture_s[c] = float(frame["capture_time_s"])
    if "ball_in_flight" in info:
        row["ball_in_flight"] = np.asarray(bool(info["ball_in_flight"]))
    if "applied_action" in info:  # None before the first action (BallTable's reset)
        applied = info["applied_action"]
        row["applied_action"] = (
            np.full(env.unwrapped.action_space.shape, np.nan)  # type: ignore[arg-type]
            if applied is None
            else np.array(applied, dtype=np.float64)
        )
    camera = info.get("camera")
    if isinstance(camera, Mapping) and "T_world_cam" in camera:
        row["camera_T_world_cam"] = np.array(camera["T_world_cam"], dtype=np.float64)
    estimate = info.get("estimate")
    if estimate is not None:
        row["estimate_mean"] = np.array(estimate["mean"], dtype=np.float64)
        row["estimate_covariance"] = np.array(estimate["covariance"], dtype=np.float64)
        nis = estimate.get("nis")
        row["estimate_nis"] = np.asarray(np.nan if nis is None else float(nis))
    return row


class KeepObservation(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Passes everything through and keeps the env's newest observation
    (``kept_observation``): what the observer was given, before a wrapper above (the
    observer's :class:`~observer_gym.estimation.VisionObserver`) replaces it by its
    estimate."""

    def __init__(self, env: gym.Env):
        gym.utils.RecordConstructorArgs.__init__(self)
        gym.Wrapper.__init__(self, env)
        self.kept_observation: Any = None

    def reset(self, **kwargs: Any) -> Any:
        options = kwargs.get("options")
        if options and MINARI_AUTOSEED in options:  # Minari's own option, no env's
            kwargs["options"] = {k: v for k, v in options.items() if k != MINARI_AUTOSEED}
        obs, info = self.env.reset(**kwargs)
        self.kept_observation = obs
        return obs, info

    def step(self, action: Any) -> Any:
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.kept_observation = obs
        return obs, reward, terminated, truncated, info


def world_stack(env: gym.Env) -> gym.Env:
    """The env stack of the current episode's world under ``env``: ``env`` itself, or,
    where the world is rebuilt every episode (a wrapper whose base env holds the
    episode's stack as ``inner``: :class:`~observer_gym.train.rl.randomize.RandomizedEnv`),
    that stack."""
    inner = getattr(env.unwrapped, "inner", None)
    return env if inner is None else inner


class RecordedStep(StepDataCallback):
    """Minari's step callback with the observation of the env's obs mode
    (:class:`KeepObservation`'s) and :func:`step_info`'s info."""

    def __call__(self, env: gym.Env, obs: Any, info: dict[str, Any], **step: Any) -> Any:
        data = super().__call__(env, obs, info, **step)
        world = world_stack(env)
        data["observation"] = world.get_wrapper_attr("kept_observation")
        data["info"] = step_info(world, info)
        return data


# a world rebuilt every episode: given the builder of the observer stack for drawn options
# (over the fixed ones), the env that rebuilds it at each reset (a RandomizedEnv)
PerEpisode = Callable[[Callable[[Mapping[str, Any]], gym.Env]], gym.Env]


def recording_env(
    system: System,
    observer: ObserverEntry,
    env_kwargs: Mapping[str, Any] | None = None,
    per_episode: PerEpisode | None = None,
    observation_space: gym.Space | None = None,
) -> minari.DataCollector:
    """:func:`~observer_gym.train.core.observer_env.make_env`'s env for ``observer`` (its
    steps, repeated here to put a wrapper between them), with :class:`KeepObservation`
    beneath the observer and Minari's DataCollector above it: the collector records the
    observations of the obs mode (camera frames losslessly, no JPEG; measurements; the
    state for ``oracle``), the actions that reached the env and the infos with the
    observer's estimate (:class:`RecordedStep`). With ``per_episode`` the collector is
    above the env it makes of the stack's builder (options drawn per episode, the world
    rebuilt at each reset), and ``observation_space`` the dataset's (one holding every
    episode's observations; default the first world's). Call inside
    :func:`staged_datasets`."""

    def make_stack(drawn: Mapping[str, Any]) -> gym.Env:
        options = with_observer_env_options(observer, {**(env_kwargs or {}), **drawn})
        check_gym_make_options(options)
        kept = KeepObservation(gym.make(system.env_id, obs_mode=observer.obs_mode, **options))
        return wrap_observer(kept, observer)

    observed = make_stack({}) if per_episode is None else per_episode(make_stack)
    return minari.DataCollector(
        observed,
        step_data_callback=RecordedStep,
        record_infos=True,
        observation_space=(
            world_stack(observed).unwrapped.observation_space
            if observation_space is None
            else observation_space
        ),
        jpeg_encoding=False,
    )


def remove_killed_stagings(out_dir: Path) -> list[Path]:
    """Remove the staging folders of ``out_dir`` (``.NAME.tmp-PID`` beside it) whose
    process is gone (a recording killed while writing), each with an
    :class:`~observer_gym.train.reports.outputs.OutputFolderWarning`; returns them."""
    removed = []
    for path in sorted(out_dir.parent.glob(f".{glob.escape(out_dir.name)}.tmp-*")):
        pid = path.name.rpartition(".tmp-")[2]
        if not pid.isdigit() or not path.is_dir() or process_alive(int(pid)):
            continue
        shutil.rmtree(path, ignore_errors=True)
        removed.append(path)
        warnings.warn(
            f"removed {path}, left by a recording into {out_dir} that was killed while writing",
            OutputFolderWarning,
            stacklevel=3,
        )
    return removed


@contextmanager
def staged_datasets(out_dir: str | os.PathLike) -> Iterator[Path]:
    """A staging folder ``.NAME.tmp-PID`` beside ``out_dir`` (which must not exist), with
    ``MINARI_DATASETS_PATH`` pointing at it inside the block; renamed to ``out_dir`` if the
    block ends normally (SIGINT and SIGTERM held meanwhile), removed if it raises."""
    out_dir = Path(out_dir).absolute()  # Minari joins its paths to a relative one twice
    staging = out_dir.with_name(f".{out_dir.name}.tmp-{os.getpid()}")
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    remove_killed_stagings(out_dir)
    staging.mkdir()
    before = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = str(staging)
    try:
        yield staging
        with signals_deferred():
            os.rename(staging, out_dir)  # fails (OSError) if out_dir appeared meanwhile
    finally:
        if before is None:
            os.environ.pop("MINARI_DATASETS_PATH", None)
        else:
            os.environ["MINARI_DATASETS_PATH"] = before
        shutil.rmtree(staging, ignore_errors=True)


def set_drawn_episodes(
    dataset: minari.MinariDataset, drawn: list[tuple[int, Mapping[str, Any]]]
) -> None:
    """Write each episode's world seed and drawn options (``(seed, options)`` per episode,
    in order) into its Minari episode metadata: ``seed`` (the seed the world was reset
    with; Minari's own is None, the reset having been given none) and
    ``drawn_options/KEY`` (read back as the ``drawn_options`` dict)."""
    dataset.storage.update_episode_metadata(
        [
            {"seed": int(seed), **{f"{DRAWN_OPTIONS}/{k}": v for k, v in options.items()}}
            for seed, options in drawn
        ],
        range(len(drawn)),
    )


def recording_record(out_dir: str | os.PathLike) -> dict[str, Any]:
    """What ``record.json`` of the recording ``out_dir`` holds (``dataset_id``, ``config``,
    ``versions``); ValueError if ``out_dir`` holds no recording."""
    path = Path(out_dir) / RECORD_FILE
    if not path.is_file():
        raise ValueError(f"{out_dir} holds no recording (no {RECORD_FILE})")
    record = read_json(path)
    if not isinstance(record, dict) or "dataset_id" not in record:
        raise ValueError(f"{path} names no dataset_id")
    return record


def load_recording(out_dir: str | os.PathLike) -> minari.MinariDataset:
    """The Minari dataset ``observer-gym record`` wrote into ``out_dir`` (the same as
    ``minari.load_dataset(ID)`` with ``MINARI_DATASETS_PATH=out_dir``)."""
    dataset_id = recording_record(out_dir)["dataset_id"]
    return minari.MinariDataset(Path(out_dir) / dataset_id / "data")


@dataclasses.dataclass(frozen=True)
class RecordedEpisode:
    """One recorded episode of T steps, as arrays (units as :func:`step_info`'s)."""

    episode_id: int
    seed: int | None  # the reset's seed: replaying ``actions`` from it gives the episode
    # the options drawn for the episode's world (a randomised recording), else empty:
    # replaying needs them over the recording's fixed options
    drawn_options: Mapping[str, Any]
    observations: Any  # (T + 1, ...) the env's obs mode (a dict of arrays for a Dict space)
    actions: np.ndarray  # (T, m)
    rewards: np.ndarray  # (T,)
    terminations: np.ndarray  # (T,) bool
    truncations: np.ndarray  # (T,) bool
    time_s: np.ndarray  # (T + 1,) s
    state: np.ndarray  # (T + 1, n) ground truth
    estimate_mean: np.ndarray | None  # (T + 1, n), None without an observer's estimate
    estimate_covariance: np.ndarray | None  # (T + 1, n, n)
    infos: Mapping[str, np.ndarray]  # every info array, (T + 1, ...) each


def episodes_of(dataset: minari.MinariDataset) -> list[RecordedEpisode]:
    """The episodes of a recorded dataset (:func:`load_recording` or
    ``minari.load_dataset``), in order."""
    ids = list(dataset.episode_indices)
    metadatas = list(dataset.storage.get_episode_metadata(ids))
    episodes = []
    for episode, metadata in zip(dataset.iterate_episodes(ids), metadatas, strict=True):
        infos = {key: np.asarray(value) for key, value in episode.infos.items()}
        seed = metadata.get("seed")
        drawn = {k: _plain(v) for k, v in metadata.get(DRAWN_OPTIONS, {}).items()}
        episodes.append(
            RecordedEpisode(
                episode_id=int(episode.id),
                seed=None if seed is None else int(seed),
                drawn_options=drawn,
                observations=episode.observations,
                actions=np.asarray(episode.actions),
                rewards=np.asarray(episode.rewards),
                terminations=np.asarray(episode.terminations, dtype=bool),
                truncations=np.asarray(episode.truncations, dtype=bool),
                time_s=infos["time_s"],
                state=infos["state"],
                estimate_mean=infos.get("estimate_mean"),
                estimate_covariance=infos.get("estimate_covariance"),
                infos=infos,
            )
        )
    return episodes


def _plain(value: Any) -> Any:
    """An HDF5 attribute as the Python value it was written from (a NumPy scalar's item)."""
    return value.item() if isinstance(value, np.generic) else value


def read_recording(out_dir: str | os.PathLike) -> list[RecordedEpisode]:
    """The episodes ``observer-gym record`` wrote into ``out_dir``, as arrays."""
    return episodes_of(load_recording(out_dir))
