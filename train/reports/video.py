"""Videos of episodes: each frame the camera image the observer received, with overlays.

:class:`EpisodeVideo` writes one MP4 per camera of one episode while it runs: after the
reset and after every step, :meth:`EpisodeVideo.add` takes the step's ``info`` and draws
each delivered frame (:func:`~observer_gym.train.reports.episode_frames.delivered_frames`)
with OpenCV: the observer's detection (yellow ring), the truth projected through the true
camera (cyan cross) and, when the env sets a calibration error, through the nominal
calibration too (cyan ring: the two differ by the calibration error's effect in pixels),
the estimate projected through the nominal calibration (magenta dot) with its 2-sigma
ellipse (the covariance through the projection's Jacobian), the
frame's capture-to-delivery age in ms and the frames dropped since the camera's last one
(red); beside the image a strip of the estimate's error and the controller's action over
the last :data:`STRIP_STEPS` steps.

The frames go to ffmpeg (imageio-ffmpeg, the ``[video]`` extra) as they come: nothing
holds more than one frame and the strip's last steps, so memory stays flat however long
the episode. Each file is written under a temp name beside it, ``.NAME.tmp-PID`` (the
house's pattern, :data:`~observer_gym.train.reports.outputs.TEMP_PATTERNS`: a run killed
with SIGKILL leaves a temp that the next command into the folder removes) and renamed
into place with SIGINT and SIGTERM held when the episode ends; an episode that fails or is
interrupted removes its temps, so no half-written file is ever presented as whole.
"""

from __future__ import annotations

import collections
import dataclasses
import math
import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from observer_gym.train.core.atomic_write import WriteError
from observer_gym.train.core.signals import signals_deferred
from observer_gym.train.reports.episode_frames import (
    DeliveredFrame,
    delivered_frames,
    marker_pixels,
    projection_for,
)
from observer_gym.train.reports.outputs import check_writable_folder

# The overlays' colours (RGB, as the frames are)
ESTIMATE_RGB = (255, 0, 255)
TRUTH_RGB = (0, 255, 255)
DETECTION_RGB = (255, 255, 0)
DROPPED_RGB = (255, 40, 40)
TEXT_RGB = (255, 255, 255)
ESTIMATE_DOT_PX = 3  # the estimate's dot's radius in the video's pixels
TRUTH_CROSS_PX = 20  # the truth's cross's size in the video's pixels
STRIP_STEPS = 200  # the strip shows the error and the action over this many last steps
STRIP_WIDTH_PX = 320
# The estimate error the strip plots, per system: the state entries, their unit and scale
ERROR_ENTRIES = {
    "ball_table": (slice(0, 2), "mm", 1e3),
    "ball_catcher": (slice(0, 3), "mm", 1e3),
    "target_follower": (slice(0, 2), "px", 1.0),
}


@dataclasses.dataclass(frozen=True)
class VideoRequest:
    """Where an episode's video goes: the folder and the file names' stem (the camera's
    id is appended where the env has several)."""

    folder: str
    stem: str


def video_stem(env_id: str, observer: str, controller: str, episode: int, seed: int) -> str:
    """A file-name stem for episode ``episode`` (its index in the run) of a pair: the
    names (an agent ``ALGO:PATH`` as ``ALGO-FOLDER``) with what a file name cannot hold
    replaced by ``-``, cut to 120 characters."""
    short = env_id.rsplit("/", 1)[-1]
    if ":" in controller:  # an agent, ALGO:PATH: its algorithm and folder's name
        algo, path = controller.split(":", 1)
        controller = f"{algo}-{Path(path).name}"
    names = re.sub(r"[^A-Za-z0-9._=-]+", "-", f"{short}_{observer}_{controller}")
    return f"{names[:120]}_episode{episode}_seed{seed}"


def check_video_folder(folder: str | os.PathLike) -> Path:
    """Create ``folder`` if needed and check that files can be made in it; WriteError
    naming it (one line) if not. Before any episode runs, so a run into a folder it
    cannot write is refused at once. Removes the temps there of writers that are gone (a
    run killed with SIGKILL: :func:`~observer_gym.train.reports.outputs.remove_stale_temps`,
    with a warning naming them)."""
    return check_writable_folder(folder, f"videos into {Path(folder)}")


def check_video_observer(obs_mode: str, observer: str) -> None:
    """ValueError (one line) unless ``observer`` reads camera pixels: a video shows the
    images the observer received, and in ``measurements`` and ``state`` modes it
    received none."""
    if obs_mode != "rgb":
        raise ValueError(
            f"--video shows the camera images the observer received, and observer "
            f"{observer!r} reads {obs_mode} (obs_mode {obs_mode!r}), not images: choose an "
            "observer with obs_mode 'rgb' (e.g. kf instead of kf-measurements)"
        )


class _Stream:
    """One camera's MP4: ffmpeg fed frame by frame, into a temp renamed at the end."""

    def __init__(self, path: Path, size_px: tuple[int, int], fps: float) -> None:
        import imageio_ffmpeg  # the [video] extra, checked before any episode

        self.path = path
        self.tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
        self.frames = 0
        try:
            self._writer = imageio_ffmpeg.write_frames(
                str(self.tmp),
                size_px,
                fps=fps,
                codec="libx264",
                quality=None,
                macro_block_size=16,
                output_params=["-crf", "18", "-preset", "veryfast", "-f", "mp4"],
            )
            self._writer.send(None)  # starts ffmpeg
        except (OSError, RuntimeError) as exc:
            self.tmp.unlink(missing_ok=True)
            raise WriteError(f"could not write {path}: {exc}") from exc

    def send(self, frame: np.ndarray) -> None:
        try:
            self._writer.send(np.ascontiguousarray(frame))
        except (OSError, RuntimeError) as exc:  # ffmpeg gone: a full disk, a killed encoder
            self.abort()
            raise WriteError(f"could not write {self.path}: {' '.join(str(exc).split())}") from exc
        self.frames += 1

    def finish(self) -> None:
        try:
            self._writer.close()  # ffmpeg writes the index (moov) and exits
            with signals_deferred():
                os.replace(self.tmp, self.path)
        except (OSError, RuntimeError) as exc:
            raise WriteError(f"could not write {self.path}: {' '.join(str(exc).split())}") from exc
        finally:
            self.tmp.unlink(missing_ok=True)

    def abort(self) -> None:
        try:
            self._writer.close()
        except Exception:  # the file is dropped whatever ffmpeg says
            pass
        self.tmp.unlink(missing_ok=True)


class FrameOverlay:
    """Draws what the observer made of each delivered frame on its image (OpenCV): the
    detection, the truth through the true camera (and through the nominal one under a
    calibration error), the estimate with its 2-sigma ellipse, the frame's age and the
    frames dropped since the camera's last one (so it keeps each camera's last capture
    time: one instance per episode). What a video frame (:class:`EpisodeVideo`) and a
    rerun recording (:mod:`observer_gym.train.reports.rerun_recording`) show."""

    def __init__(self, env: Any) -> None:
        base = env.unwrapped
        self.period_s = 1.0 / float(base.config.frame_rate_hz)
        self.projection = projection_for(base)
        self.last_capture_s: dict[int, float] = {}

    def scale_of(self, image: np.ndarray) -> int:
        """The image's enlargement in the video (small frames are doubled to read)."""
        return 2 if image.shape[0] < 400 else 1

    def draw(self, frame: DeliveredFrame) -> np.ndarray:
        """``frame``'s image, enlarged by :meth:`scale_of`, with its overlays."""
        assert frame.image is not None
        scale = self.scale_of(frame.image)
        image = cv2.resize(frame.image, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
        height = image.shape[0]

        def at(uv: np.ndarray) -> tuple[int, int]:
            return round(float(uv[0]) * scale), round(float(uv[1]) * scale)

        def inside(uv: np.ndarray) -> bool:
            return bool(np.all(np.abs(uv) < 1e5))

        if self.projection is not None:
            truth = marker_pixels(
                self.projection, frame.state, frame.K_true, frame.T_world_cam_true
            )
            if truth is not None and inside(truth.uv_px):
                cv2.drawMarker(
                    image, at(truth.uv_px), TRUTH_RGB, cv2.MARKER_CROSS, TRUTH_CROSS_PX, 2
                )
            if frame.calibration_differs:  # where the nominal calibration puts the truth
                seen = marker_pixels(self.projection, frame.state, frame.K, frame.T_world_cam)
                if seen is not None and inside(seen.uv_px):
                    cv2.circle(image, at(seen.uv_px), 4 * scale, TRUTH_RGB, 1, cv2.LINE_AA)
        if frame.detection_px is not None and inside(frame.detection_px):
            cv2.circle(image, at(frame.detection_px), 5 * scale, DETECTION_RGB, 1, cv2.LINE_AA)
        if self.projection is not None and frame.estimate is not None:
            marker = marker_pixels(
                self.projection, frame.estimate, frame.K, frame.T_world_cam, frame.covariance
            )
            if marker is not None and inside(marker.uv_px):
                if marker.covariance_px2 is not None:
                    self._ellipse(image, marker.uv_px, marker.covariance_px2, scale)
                cv2.circle(image, at(marker.uv_px), ESTIMATE_DOT_PX, ESTIMATE_RGB, -1)
        lines = [
            f"t {frame.delivery_time_s:6.2f} s  cam {frame.camera_id}",
            f"age {frame.age_ms:5.1f} ms",
        ]
        cv2.rectangle(image, (0, 0), (190, 8 + 18 * len(lines)), (0, 0, 0), -1)
        for row, text in enumerate(lines):
            cv2.putText(
                image,
                text,
                (6, 18 + 18 * row),
                cv2.FONT_HERSHEY_SIMPLEX,
                0.5,
                TEXT_RGB,
                1,
                cv2.LINE_AA,
            )
        last = self.last_capture_s.get(frame.camera_id)
        dropped = (
            0 if last is None else max(0, round((frame.capture_time_s - last) / self.period_s) - 1)
        )
        self.last_capture_s[frame.camera_id] = frame.capture_time_s
        if dropped:
            cv2.putText(
                image,
                f"{dropped} dropped",
                (6, 54),
                cv2.FONT_HERSHEY_SIMPLEX,
                0.5,
                DROPPED_RGB,
                1,
                cv2.LINE_AA,
            )
            cv2.rectangle(image, (0, 0), (image.shape[1] - 1, height - 1), DROPPED_RGB, 2)
        return image

    @staticmethod
    def _ellipse(image: np.ndarray, uv: np.ndarray, covariance: np.ndarray, scale: int) -> None:
        """The 2-sigma ellipse of the pixel covariance (2, 2) around ``uv``."""
        values, vectors = np.linalg.eigh(0.5 * (covariance + covariance.T))
        values = np.maximum(values, 0.0)
        axes = tuple(int(min(2.0 * math.sqrt(v) * scale, 4000)) for v in values)
        angle = math.degrees(math.atan2(vectors[1, 0], vectors[0, 0]))
        centre = (round(float(uv[0]) * scale), round(float(uv[1]) * scale))
        cv2.ellipse(image, centre, axes, angle, 0, 360, ESTIMATE_RGB, 1, cv2.LINE_AA)


class EpisodeVideo:
    """The videos of one episode (one per camera), written as the episode runs.

    Call :meth:`add` with the reset's ``info`` (``step`` 0, no action) and each step's,
    then :meth:`finish`; on any failure :meth:`abort` removes the temps (use it as a
    context manager: ``finish`` on a normal exit, ``abort`` on an exception). ``fps``:
    the video's frame rate (default the camera's frame rate, so it plays in real time).
    """

    def __init__(self, request: VideoRequest, env: Any, fps: float | None = None) -> None:
        from observer_gym.envs import system_of

        self.folder = Path(request.folder)
        self.stem = request.stem
        base = env.unwrapped
        self.env = env
        self.num_cameras = int(base.rig.num_cameras)
        self.fps = float(fps if fps is not None else base.config.frame_rate_hz)
        self.overlay = FrameOverlay(env)
        self.error_entries = ERROR_ENTRIES.get(system_of(base).name)
        self.streams: dict[int, _Stream] = {}
        self.errors: collections.deque[float] = collections.deque(maxlen=STRIP_STEPS)
        self.actions: collections.deque[np.ndarray] = collections.deque(maxlen=STRIP_STEPS)
        self.action_low = np.asarray(getattr(env.action_space, "low", [-1.0]), dtype=float)
        self.action_high = np.asarray(getattr(env.action_space, "high", [1.0]), dtype=float)
        self.paths: list[Path] = []

    def path_for(self, camera_id: int) -> Path:
        suffix = f"_camera{camera_id}" if self.num_cameras > 1 else ""
        return self.folder / f"{self.stem}{suffix}.mp4"

    def add(self, info: Mapping[str, Any], step: int, action: np.ndarray | None = None) -> None:
        """Draw and send the frames ``info`` delivers (the reset's with ``step`` 0)."""
        if action is not None:
            self.actions.append(np.asarray(action, dtype=float).reshape(-1))
        estimate = info.get("estimate")
        if estimate is not None and self.error_entries is not None:
            entries, _, scale = self.error_entries
            difference = np.asarray(estimate["mean"])[entries] - np.asarray(info["state"])[entries]
            self.errors.append(float(np.linalg.norm(difference) * scale))
        for frame in delivered_frames(self.env, info, step):
            if frame.image is None:
                continue
            drawn = self.draw(frame)
            stream = self.streams.get(frame.camera_id)
            if stream is None:
                stream = _Stream(
                    self.path_for(frame.camera_id), (drawn.shape[1], drawn.shape[0]), self.fps
                )
                self.streams[frame.camera_id] = stream
            stream.send(drawn)

    @property
    def frames_written(self) -> dict[int, int]:
        return {camera: stream.frames for camera, stream in self.streams.items()}

    def finish(self) -> list[Path]:
        """Close the encoders and move the files into place; their paths."""
        for camera in sorted(self.streams):
            stream = self.streams.pop(camera)
            try:
                stream.finish()
            except BaseException:
                self.abort()
                raise
            self.paths.append(stream.path)
        return self.paths

    def abort(self) -> None:
        """Stop the encoders and remove the temps; nothing is renamed into place."""
        for stream in self.streams.values():
            stream.abort()
        self.streams.clear()

    def __enter__(self) -> EpisodeVideo:
        return self

    def __exit__(self, kind, value, traceback) -> None:
        if kind is None:
            self.finish()
        else:
            self.abort()

    # drawing

    def draw(self, frame: DeliveredFrame) -> np.ndarray:
        """The video frame of ``frame``: the image with its overlays
        (:meth:`FrameOverlay.draw`), and the strip."""
        image = self.overlay.draw(frame)
        canvas = np.concatenate([image, self._strip(image.shape[0])], axis=1)
        # ffmpeg's yuv420p wants sizes in whole macroblocks: pad with black, never resize
        pad_h, pad_w = -canvas.shape[0] % 16, -canvas.shape[1] % 16
        if pad_h or pad_w:
            canvas = cv2.copyMakeBorder(canvas, 0, pad_h, 0, pad_w, cv2.BORDER_CONSTANT, value=0)
        return canvas

    def _strip(self, height: int) -> np.ndarray:
        """The estimate error (top) and the action (bottom, one line per entry, scaled to
        the action's bounds) over the last :data:`STRIP_STEPS` steps."""
        strip = np.full((height, STRIP_WIDTH_PX, 3), 32, dtype=np.uint8)
        half = height // 2
        width = STRIP_WIDTH_PX - 12

        def xs(count: int) -> np.ndarray:
            return 6 + np.arange(count) * width / max(STRIP_STEPS - 1, 1)

        if self.errors and self.error_entries is not None:
            errors = np.array(self.errors)
            top = max(float(np.nanmax(errors)), 1e-9)
            ys = half - 8 - (half - 30) * np.clip(errors / top, 0, 1)
            points = np.column_stack([xs(errors.size), ys]).astype(np.int32)
            cv2.polylines(strip, [points], False, ESTIMATE_RGB, 1, cv2.LINE_AA)
            unit = self.error_entries[1]
            label = f"error {errors[-1]:.1f} {unit} (max {top:.1f})"
            cv2.putText(
                strip, label, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, TEXT_RGB, 1, cv2.LINE_AA
            )
        cv2.line(strip, (0, half), (STRIP_WIDTH_PX - 1, half), (90, 90, 90), 1)
        if self.actions:
            actions = np.array(self.actions)
            low, high = self.action_low, self.action_high
            span = np.where(np.isfinite(high - low) & (high > low), high - low, 2.0)
            low = np.where(np.isfinite(low), low, -1.0)
            colours = [(0, 200, 255), (255, 160, 0), (200, 200, 200), (120, 255, 120)]
            for k in range(actions.shape[1]):
                fraction = np.clip((actions[:, k] - low[k % low.size]) / span[k % span.size], 0, 1)
                ys = height - 58 - (half - 84) * fraction  # above the legend
                points = np.column_stack([xs(actions.shape[0]), ys]).astype(np.int32)
                cv2.polylines(strip, [points], False, colours[k % len(colours)], 1, cv2.LINE_AA)
            cv2.putText(
                strip,
                "action (bounds)",
                (6, half + 16),
                cv2.FONT_HERSHEY_SIMPLEX,
                0.45,
                TEXT_RGB,
                1,
                cv2.LINE_AA,
            )
        legend = (
            ("estimate, 2-sigma", ESTIMATE_RGB),
            ("truth (ring: through the nominal camera)", TRUTH_RGB),
            ("detection", DETECTION_RGB),
        )
        for row, (text, colour) in enumerate(legend):
            y = height - 10 - 16 * (len(legend) - 1 - row)
            cv2.circle(strip, (12, y - 4), 4, colour, -1)
            cv2.putText(
                strip,
                text,
                (22, y),
                cv2.FONT_HERSHEY_SIMPLEX,
                0.4,
                TEXT_RGB,
                1,
                cv2.LINE_AA,
            )
        return strip


def chosen_episodes(
    episodes: Sequence[int] | None, count: int, what: str = "video"
) -> tuple[int, ...]:
    """The episode indices to film or record (default the first); ValueError naming
    ``what`` chose them and the allowed range for one outside 0..count-1."""
    chosen = (0,) if episodes is None else tuple(int(e) for e in episodes)
    bad = [e for e in chosen if not 0 <= e < count]
    if bad:
        raise ValueError(
            f"{what} episodes {bad} are outside the run's episodes 0..{count - 1} "
            "(indices from 0: episode i resets with seed + i)"
        )
    return chosen
