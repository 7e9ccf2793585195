"""The camera rig: when each camera captures, what it sees, when each frame arrives.

One :class:`CameraRig` serves every env. It owns the sensor model of
:mod:`observer_gym.envs.sensor` for one or more cameras:

- the schedule (:class:`FrameClock`): capture times on physics ticks, jitter, drops,
  latency, delivery in capture-time order;
- the calibration error of each camera (:class:`CalibrationError`), drawn at reset;
- capture: a rendered image (with image noise) or the env's perfect measurement through
  the *true* camera, recorded with the *nominal* calibration an observer may know;
- delivery: the frames due by a tick, and the newest delivered frame of each camera.

Times are whole physics ticks, so a frame is made from exactly the world at its capture
tick and every time is exact (tick x tick_s).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from observer_gym.envs.camera import Camera, PinholeIntrinsics
from observer_gym.envs.sensor import SensorConfig
from observer_gym.envs.sim import Simulation
from observer_gym.envs.transforms import pose_matrix

_DIAGONAL_2 = np.array([1.0, 1.0]) / math.sqrt(2.0)
_DIAGONAL_3 = np.array([1.0, 1.0, 1.0]) / math.sqrt(3.0)


@dataclass(frozen=True)
class CameraTiming:
    """A camera's capture phase (s after reset) and latency (s from capture to delivery)."""

    phase_s: float
    latency_s: float


@dataclass(frozen=True)
class CalibrationError:
    """How a real camera differs from its nominal calibration.

    ``K_true = [[s fx, 0, cx + dx], [0, s fy, cy + dy], [0, 0, 1]]`` with
    ``s = focal_scale`` and ``(dx, dy) = principal_point_offset_px``;
    ``T_world_cam_true = T_world_cam_nominal @ T_nominal_true``.
    """

    focal_scale: float = 1.0
    principal_point_offset_px: tuple[float, float] = (0.0, 0.0)
    T_nominal_true: np.ndarray = field(default_factory=lambda: np.eye(4))

    def true_intrinsics(self, nominal: PinholeIntrinsics) -> PinholeIntrinsics:
        dx, dy = self.principal_point_offset_px
        return dataclasses.replace(
            nominal,
            fx_px=nominal.fx_px * self.focal_scale,
            fy_px=nominal.fy_px * self.focal_scale,
            cx_px=nominal.cx_px + dx,
            cy_px=nominal.cy_px + dy,
        )

    @property
    def is_exact(self) -> bool:
        """The real camera is the nominal one."""
        return (
            self.focal_scale == 1.0
            and self.principal_point_offset_px == (0.0, 0.0)
            and np.array_equal(self.T_nominal_true, np.eye(4))
        )

    def true_pose(self, T_world_cam_nominal: np.ndarray) -> np.ndarray:
        return T_world_cam_nominal @ self.T_nominal_true


def _readonly(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


def _rotation_about(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """Rodrigues' formula: the rotation by ``angle_rad`` about the unit vector ``axis``."""
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + math.sin(angle_rad) * k + (1.0 - math.cos(angle_rad)) * (k @ k)


def _unit(rng: np.random.Generator | None, fixed: np.ndarray) -> np.ndarray:
    """``fixed``, or a direction uniform on the circle / sphere of its dimension."""
    if rng is None:
        return fixed
    v = rng.normal(size=fixed.shape)
    return v / np.linalg.norm(v)


def draw_calibration_error(cfg: SensorConfig, rng: np.random.Generator) -> CalibrationError:
    """One camera's calibration error under ``cfg`` (the sizes are exact; the directions
    come from ``rng`` when ``cfg.calib_error_draw == "per_episode"``)."""
    if not cfg.has_calibration_error:
        return CalibrationError()
    draw = rng if cfg.calib_error_draw == "per_episode" else None
    sign = 1.0 if draw is None else float(draw.choice([-1.0, 1.0]))
    offset = cfg.calib_principal_point_error_px * _unit(draw, _DIAGONAL_2)
    rotation = _rotation_about(_unit(draw, _DIAGONAL_3), math.radians(cfg.calib_rotation_error_deg))
    translation = cfg.calib_translation_error_m * _unit(draw, _DIAGONAL_3)
    return CalibrationError(
        focal_scale=1.0 + sign * cfg.calib_focal_error,
        principal_point_offset_px=(float(offset[0]), float(offset[1])),
        T_nominal_true=pose_matrix(rotation, translation),
    )


@dataclass(slots=True)
class Frame:
    """A captured frame: when, through which calibration, and what it holds (the
    calibration arrays are read-only: frames and ``info`` share them)."""

    camera_id: int
    capture_tick: int
    delivery_tick: int
    K: np.ndarray  # nominal: what the rig's calibration says
    T_world_cam: np.ndarray  # nominal pose at the capture
    K_true: np.ndarray
    T_world_cam_true: np.ndarray
    payload: Any  # an image (rgb), a measurement (measurements) or None (state)


@dataclass
class _CameraSchedule:
    timing: CameraTiming
    index: int = 0  # the next frame's number
    next_tick: int = 0
    last_tick: int = -1
    lost: int = 0  # frames captured and lost (drops) since the reset


class FrameClock:
    """Capture and delivery schedule of every camera for one episode.

    Camera c captures its k-th frame at ``phase_c + k / rate`` (+ Gaussian jitter, clipped
    to a quarter period, rounded to a tick and kept after the previous capture). A frame
    is lost with probability ``drop_prob`` (one uniform draw per frame when > 0; frames at
    tick 0 are never lost and draw nothing). A kept
    frame is delivered ``latency_c`` (+ Gaussian latency jitter, kept >= 0) after its
    capture, rounded to a tick.

    Args:
        rng: the sensor's timing stream (spawned from the env's generator at reset), drawn
            in a fixed order so episodes are reproducible.
    """

    def __init__(
        self,
        timings: Sequence[CameraTiming],
        rate_hz: float,
        tick_s: float,
        rng: np.random.Generator,
        jitter_s: float = 0.0,
        latency_jitter_s: float = 0.0,
        drop_prob: float = 0.0,
    ) -> None:
        self.rate_hz = float(rate_hz)
        self.tick_s = float(tick_s)
        self.rng = rng
        self.jitter_s = float(jitter_s)
        self.latency_jitter_s = float(latency_jitter_s)
        self.drop_prob = float(drop_prob)
        self.schedules = [_CameraSchedule(t) for t in timings]
        for schedule in self.schedules:
            schedule.next_tick = self._draw_tick(schedule)
        self._next_tick = min(s.next_tick for s in self.schedules)  # next_capture_tick()

    def _draw_tick(self, schedule: _CameraSchedule) -> int:
        t = schedule.timing.phase_s + schedule.index / self.rate_hz
        if self.jitter_s > 0.0:
            limit = 0.25 / self.rate_hz
            t += float(np.clip(self.rng.normal(0.0, self.jitter_s), -limit, limit))
        return max(round(t / self.tick_s), schedule.last_tick + 1, 0)

    def captures_at(self, tick: int) -> list[int]:
        """The cameras that capture a kept frame at ``tick`` (advancing their schedules)."""
        if tick < self._next_tick:  # no camera's next capture: nothing to advance or draw
            return []
        cameras = []
        for camera_id, schedule in enumerate(self.schedules):
            if schedule.next_tick != tick:
                continue
            schedule.last_tick = tick
            schedule.index += 1
            schedule.next_tick = self._draw_tick(schedule)
            if tick > 0 and self.drop_prob > 0.0:
                if self.rng.random() < self.drop_prob:  # uniform()'s number, cheaper
                    schedule.lost += 1
                    continue
            cameras.append(camera_id)
        schedules = self.schedules
        self._next_tick = (
            schedules[0].next_tick if len(schedules) == 1 else min(s.next_tick for s in schedules)
        )
        return cameras

    def next_capture_tick(self) -> int:
        """The earliest tick at which some camera captures next (its frame may be lost)."""
        return self._next_tick

    def frames_lost(self) -> list[int]:
        """Per camera, the frames lost (dropped at capture) since the reset."""
        return [schedule.lost for schedule in self.schedules]

    def delivery_tick(self, camera_id: int, capture_tick: int) -> int:
        """When a frame of ``camera_id`` captured at ``capture_tick`` arrives."""
        latency_s = self.schedules[camera_id].timing.latency_s
        if self.latency_jitter_s > 0.0:
            latency_s = max(latency_s + float(self.rng.normal(0.0, self.latency_jitter_s)), 0.0)
        return capture_tick + round(latency_s / self.tick_s)


Measure = Callable[[int, np.ndarray, np.ndarray], Any]


class CameraRig:
    """The cameras of one env: schedule, calibration errors, capture and delivery.

    Args:
        sim: the world to render.
        intrinsics: each camera's nominal calibration.
        config: the env's sensor options.
        near_m, far_m: the renderer's clipping planes.
    """

    def __init__(
        self,
        sim: Simulation,
        intrinsics: Sequence[PinholeIntrinsics],
        config: SensorConfig,
        near_m: float,
        far_m: float,
    ) -> None:
        self.sim = sim
        self.nominal = list(intrinsics)
        self.config = config
        self.near_m, self.far_m = near_m, far_m
        self.num_cameras = len(self.nominal)
        self.image_size_px = (config.image_width_px, config.image_height_px)
        self._K_nominal = [_readonly(i.K) for i in self.nominal]  # every frame shares them
        self.errors = [CalibrationError() for _ in self.nominal]
        self._exact = [True] * self.num_cameras
        self.cameras = [Camera(sim, i, near_m, far_m) for i in self.nominal]
        self.clock: FrameClock | None = None
        self.noise_rng: np.random.Generator | None = None
        self.pending: list[Frame] = []
        self.latest: list[Frame | None] = [None] * self.num_cameras

    @property
    def K_nominal(self) -> list[np.ndarray]:
        return self._K_nominal

    def reset(
        self, sim: Simulation, rng: np.random.Generator, timings: Sequence[CameraTiming]
    ) -> None:
        """A new episode: the schedule from ``timings``; the sensor's noise, calibration
        and timing streams spawned from the env's ``rng`` (spawning draws nothing from
        it, so the world's draws do not depend on the sensor)."""
        cfg = self.config
        self.sim = sim
        self.noise_rng, calibration_rng, timing_rng = rng.spawn(3)
        self.clock = FrameClock(
            timings,
            cfg.frame_rate_hz,
            sim.physics_dt_s,
            timing_rng,
            jitter_s=cfg.jitter_s,
            latency_jitter_s=cfg.latency_jitter_s,
            drop_prob=cfg.frame_drop_prob,
        )
        self.errors = [draw_calibration_error(cfg, calibration_rng) for _ in self.nominal]
        self._exact = [e.is_exact for e in self.errors]
        self.cameras = [
            Camera(sim, e.true_intrinsics(i), self.near_m, self.far_m)
            for e, i in zip(self.errors, self.nominal, strict=True)
        ]
        for camera in self.cameras:
            _readonly(camera.K)
        self.pending = []
        self.latest = [None] * self.num_cameras

    def default_timings(self) -> list[CameraTiming]:
        cfg = self.config
        return [CameraTiming(cfg.frame_phase_s, cfg.latency_s) for _ in self.nominal]

    def next_capture_tick(self) -> int:
        """The earliest tick at which some camera captures next (its frame may be lost)."""
        assert self.clock is not None, "reset() first"
        return self.clock.next_capture_tick()

    def frames_lost(self) -> list[int]:
        """Per camera, the frames dropped at capture since the reset: the ground truth of
        what the observer never receives (it sees only gaps in the capture times)."""
        assert self.clock is not None, "reset() first"
        return self.clock.frames_lost()

    def due(self, tick: int) -> list[int]:
        """The cameras that capture a kept frame at ``tick`` (drawing jitters and drops)."""
        assert self.clock is not None, "reset() first"
        return self.clock.captures_at(tick)

    def capture(
        self,
        cameras: Sequence[int],
        tick: int,
        poses: Callable[[int], np.ndarray],
        measure: Measure | None,
    ) -> None:
        """Capture a frame with each of ``cameras`` from the world as it is now.

        Args:
            poses: camera id -> its nominal ``T_world_cam`` now.
            measure: (camera id, true K, true T_world_cam) -> the perfect measurement
                (used in ``obs_mode="measurements"``).
        """
        mode = self.config.obs_mode
        assert self.clock is not None, "reset() first"
        for c in cameras:
            T_nominal = _readonly(poses(c).copy())
            T_true = T_nominal if self._exact[c] else _readonly(self.errors[c].true_pose(T_nominal))
            camera = self.cameras[c]
            payload = None
            if mode == "rgb":
                payload = self._noisy(camera.render(T_true))
            elif mode == "measurements":
                assert measure is not None, "measurements mode needs a measure"
                payload = measure(c, camera.K, T_true)
            frame = Frame(
                c,
                tick,
                self.clock.delivery_tick(c, tick),
                self._K_nominal[c],
                T_nominal,
                camera.K,
                T_true,
                payload,
            )
            self.pending.append(frame)

    def _noisy(self, image: np.ndarray) -> np.ndarray:
        std = self.config.image_noise_std
        if std <= 0.0:
            return image
        assert self.noise_rng is not None, "reset() first"
        noise = self.noise_rng.normal(0.0, std, image.shape)
        return np.clip(np.rint(image + noise), 0, 255).astype(np.uint8)  # rounded: unbiased

    def deliver(self, tick: int) -> list[Frame]:
        """The frames due by ``tick``, in capture-time order; each camera's newest
        delivered frame is kept in :attr:`latest`."""
        due = [f for f in self.pending if f.delivery_tick <= tick]
        if not due:
            return []
        if len(due) == len(self.pending):  # the usual case: all of them
            self.pending = []
        else:
            self.pending = [f for f in self.pending if f.delivery_tick > tick]
        if len(due) > 1:
            due.sort(key=lambda f: (f.capture_tick, f.camera_id))
        for f in due:
            newest = self.latest[f.camera_id]
            if newest is None or f.capture_tick >= newest.capture_tick:
                self.latest[f.camera_id] = f
        return due

    def render_view(self, T_world_cam: np.ndarray, camera_id: int = 0) -> np.ndarray:
        """A noiseless image of the world now through camera ``camera_id``'s real optics."""
        return self.cameras[camera_id].render(T_world_cam)
