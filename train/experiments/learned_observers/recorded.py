"""A learned observer's training arrays from a recorded dataset (``observer-gym record``'s
Minari format, :mod:`observer_gym.train.reports.dataset`): the one reader of the
trainers' data.

A system's collection (its ``collect`` in this package) records its episodes with
:func:`~observer_gym.train.experiments.record.record_played` and reads them back here;
``train --dataset DIR`` reads a recording made before. The arrays are the network's
features replayed from each step's recorded observation, info and the action before it,
and the truth of that step: (features (N, n_in), truth (N, n_out), episode (N,)), the
steps before each action (a recording of T steps gives T samples per episode).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # the dataset module imports minari, which READERS' users may not have
    from observer_gym.train.reports.dataset import RecordedEpisode

__all__ = [
    "READERS",
    "ball_catcher_arrays",
    "ball_table_arrays",
    "target_follower_arrays",
    "training_arrays",
]

Arrays = tuple[np.ndarray, np.ndarray, np.ndarray]


def _step_observation(observations: Any, t: int) -> Any:
    """Step ``t``'s observation of a recorded episode (a dict of arrays for a Dict space)."""
    if isinstance(observations, dict):
        return {key: value[t] for key, value in observations.items()}
    return observations[t]


def ball_table_arrays(episodes: Sequence[RecordedEpisode]) -> Arrays:
    """BallTable's training arrays (features (N, 58), truth (N, 8), episode (N,)): each
    step's :class:`~observer_gym.estimation.ball_table.learned.LearnedFeatures` from the
    recorded measurement, the newest frame's capture time (``frame_capture_time_s``, the
    one camera's) and the action before it, as the action reached the env (float32)."""
    from observer_gym.estimation.ball_table.learned import LearnedFeatures

    xs, ys, eps = [], [], []
    for index, episode in enumerate(episodes):
        features = LearnedFeatures()
        counts = episode.infos["frame_count"][:, 0]
        captures = episode.infos["frame_capture_time_s"][:, 0]
        for t in range(len(episode.actions)):
            frames = [{"capture_time_s": captures[t]}] if counts[t] > 0 else []
            capture_s = features.newest_capture_s({"frames": frames})
            if capture_s is not None:
                features.new_frame(_step_observation(episode.observations, t), capture_s)
            action = None if t == 0 else episode.actions[t - 1]
            xs.append(features.vector(float(episode.time_s[t]), action))
            ys.append(np.asarray(episode.state[t], dtype=float))
            eps.append(index)
    return np.array(xs), np.array(ys), np.array(eps)


def target_follower_arrays(
    episodes: Sequence[RecordedEpisode], config: Mapping[str, Any]
) -> Arrays:
    """TargetFollower's training arrays (features (N, 37), truth (N, 6), episode (N,)):
    each step's :class:`~observer_gym.estimation.target_follower.learned.LearnedFeatures`
    from the recorded measurement, the newest frame's capture time, nominal K and camera
    pose, and the robot's step (``camera_T_world_cam``, ``applied_action``), kept where the
    target is tracked and a frame has shown it. Each episode's frames are read as the env
    made with the recording's options and its drawn ones reads them
    (:class:`~observer_gym.estimation.target_follower.frames.FrameReader`)."""
    import gymnasium as gym

    from observer_gym.envs.target_follower import StateIndex
    from observer_gym.estimation.target_follower.frames import FrameReader
    from observer_gym.estimation.target_follower.learned import N_OUT, LearnedFeatures
    from observer_gym.estimation.target_follower.state_layout import RobotStep

    fixed = dict(config.get("env_kwargs", {}))
    xs, ys, eps = [], [], []
    for index, episode in enumerate(episodes):
        env = gym.make("observer_gym/TargetFollower-v0", **{**fixed, **episode.drawn_options})
        try:
            base: Any = env.unwrapped
            frames = FrameReader(base, owner="recording")
            delta_y_m = base.calibration["delta_y_m"]
        finally:
            env.close()
        features = LearnedFeatures()
        infos = episode.infos
        for t in range(len(episode.actions)):
            newest = []
            if infos["frame_count"][t, 0] > 0:
                newest = [
                    {
                        "camera_id": 0,
                        "capture_time_s": infos["frame_capture_time_s"][t, 0],
                        "K": infos["K_nominal"][t, 0],
                        "T_world_cam": infos["T_world_cam_nominal"][t, 0],
                    }
                ]
            info = {
                "time_s": float(episode.time_s[t]),
                "camera": {"T_world_cam": infos["camera_T_world_cam"][t]},
                "applied_action": infos["applied_action"][t],
                "frames": newest,
            }
            robot = RobotStep.from_info(info, None, delta_y_m)
            features.add(frames.newest(_step_observation(episode.observations, t), info), robot)
            truth = np.asarray(episode.state[t], dtype=float)
            if truth[StateIndex.TRACKING_VALID] >= 0.5 and features.any_detected:
                xs.append(features.vector(robot.time_s))
                ys.append(truth[:N_OUT])
                eps.append(index)
    return np.array(xs), np.array(ys), np.array(eps)


def ball_catcher_arrays(episodes: Sequence[RecordedEpisode], config: Mapping[str, Any]) -> Arrays:
    """BallCatcher's training arrays (features (N, 65), truth (N, 6): the ball's position
    and velocity, episode (N,)): each step's
    :class:`~observer_gym.estimation.ball_catcher.learned.LearnedFeatures` from each
    camera's delivered frame (``frame_capture_time_s``, ``frame_uv_px``), the free-flight
    steps only (``ball_in_flight``).

    Raises:
        ValueError: a step delivered more frames of one camera than the recording keeps
            (its two newest; its newest only in a recording made before
            ``frame_earlier_uv_px`` was), or the recording lacks ``frame_uv_px``.
    """
    import gymnasium as gym

    from observer_gym.envs.ball_catcher.layout import BALL
    from observer_gym.estimation.ball_catcher.frames import FrameReader
    from observer_gym.estimation.ball_catcher.learned import LearnedFeatures, image_centre_px

    fixed = dict(config.get("env_kwargs", {}))
    xs, ys, eps = [], [], []
    for index, episode in enumerate(episodes):
        infos = episode.infos
        if "frame_uv_px" not in infos:
            raise ValueError("the recording keeps no frame_uv_px (BallCatcher's measurements)")
        env = gym.make("observer_gym/BallCatcher-v1", **{**fixed, **episode.drawn_options})
        try:
            base: Any = env.unwrapped
            pixels = FrameReader(base.config, owner="recording")
            features = LearnedFeatures(base.num_cameras, image_centre_px(base))
        finally:
            env.close()
        earlier = "frame_earlier_uv_px" in infos  # recorded since 2026-11-29
        kept = 2 if earlier else 1
        for t in range(len(episode.actions)):
            counts = infos["frame_count"][t]
            if counts.max(initial=0) > kept:
                raise ValueError(
                    f"episode {index} step {t} delivered {int(counts.max())} frames of one "
                    f"camera; a recording keeps each camera's {kept} newest only"
                )
            for camera in np.flatnonzero(counts > 1):  # the step's earlier frame first
                uv = infos["frame_earlier_uv_px"][t, camera]
                frame = {"uv_px": None if np.isnan(uv).any() else uv}
                capture_s = float(infos["frame_earlier_capture_time_s"][t, camera])
                features.add(int(camera), capture_s, pixels.detect(frame))
            for camera in np.flatnonzero(counts):
                uv = infos["frame_uv_px"][t, camera]
                frame = {"uv_px": None if np.isnan(uv).any() else uv}
                capture_s = float(infos["frame_capture_time_s"][t, camera])
                features.add(int(camera), capture_s, pixels.detect(frame))
            if infos["ball_in_flight"][t]:
                xs.append(features.vector(float(episode.time_s[t])))
                ys.append(np.asarray(episode.state[t][BALL], dtype=float))
                eps.append(index)
    return np.array(xs), np.array(ys), np.array(eps)


# env id -> the training arrays of its recorded episodes, given the recording's config
READERS: dict[str, Callable[[Sequence[RecordedEpisode], Mapping[str, Any]], Arrays]] = {
    "BallTable-v0": lambda episodes, config: ball_table_arrays(episodes),
    "TargetFollower-v0": target_follower_arrays,
    "BallCatcher-v1": ball_catcher_arrays,
}


def training_arrays(env_id: str, recording: str | os.PathLike) -> Arrays:
    """The training arrays of the learned observer of ``env_id`` from the recording in the
    folder ``recording``.

    Raises:
        ExtraNotInstalled: minari (the ``[record]`` extra) is not installed.
        ValueError: no reader for ``env_id`` (naming those there are), ``recording`` holds
            no recording, or one of another env or obs mode.
    """
    from observer_gym.extras import require_record

    require_record("reading a recording")
    from observer_gym.train.reports.dataset import read_recording, recording_record

    env_id = env_id.removeprefix("observer_gym/")
    if env_id not in READERS:
        raise ValueError(
            f"no reader of recorded training data for {env_id} yet; allowed: {', '.join(READERS)}"
        )
    config = recording_record(recording).get("config", {})
    recorded_env = str(config.get("env_id", "")).removeprefix("observer_gym/")
    obs_mode = config.get("env_kwargs", {}).get("obs_mode")
    if recorded_env != env_id or obs_mode != "measurements":
        raise ValueError(
            f"{recording} holds a recording of {recorded_env or 'no env'} in obs mode "
            f"{obs_mode!r}; {env_id}'s learned observer reads measurements of {env_id}"
        )
    return READERS[env_id](read_recording(recording), config)
