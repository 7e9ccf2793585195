"""``observer_gym/TargetFollower-v0``."""

from __future__ import annotations

import math
from typing import Any, cast

import numpy as np
from gymnasium import spaces

from observer_gym.envs.camera import PinholeIntrinsics
from observer_gym.envs.config import real_array, real_number
from observer_gym.envs.core import CameraEnv
from observer_gym.envs.sensor import SensorSpec
from observer_gym.envs.sim import Simulation
from observer_gym.envs.suite_knobs import SuiteKnobs
from observer_gym.envs.target_follower import geometry as geo
from observer_gym.envs.target_follower.config import TargetFollowerConfig
from observer_gym.envs.target_follower.drive import DriveLimits
from observer_gym.envs.target_follower.layout import (
    DETECTED,
    IMAGE,
    STATE_HIGH,
    STATE_LOW,
    TARGET_PX,
)
from observer_gym.envs.target_follower.measurements import empty_measurement, perfect_measurement
from observer_gym.envs.target_follower.motion import OccluderWalk, TargetMotion
from observer_gym.envs.target_follower.scene import GroundTruth, TargetFollowerScene

FAR_PLANE_M = 8.0  # the renderer's far plane: the target stays within a few metres
RESET_OPTIONS = ("target_pos_world_m", "tilt_rad", "occlusions_s")
TARGET_BOUND_M = 50.0  # reset's target_pos_world_m: every coordinate within +- this
OCCLUSION_START_MAX_S = 3600.0


class TargetFollowerEnv(CameraEnv):
    """A wheeled robot with a tilt camera keeps a moving target centred at a set size.

    ## Description
    The visual tracking system of docs/spec/follower.md (Tsai et al. 2009). A differential-drive
    robot (wheel base D = 0.40 m) carries a camera on a tilt platform whose axis is 1.20 m
    above the floor; the camera sits delta_y = 0.10 m above the axis (320x240 px,
    f_x, f_y = 393.4, 391.8 px, 10 frames/s: T = 100 ms). An orange sphere of width
    W = 0.12 m at head height is the target; it moves by the spec's profile (44), a smooth
    random walk, or not at all. Optionally a person-sized box walks between robot and
    target and hides it fully for ``occluder_hold_s``. The robot and the target move
    kinematically (the spec's unicycle model, integrated exactly); PyBullet holds the world
    and renders it with TinyRenderer (no floor, to keep rendering cheap:
    ``python benchmarks/bench_follower.py`` measures it).

    ## Action Space
    ``Box([-v_max, -omega_max, -omega_t_max], [v_max, omega_max, omega_t_max], float32)``:
    u = (v, omega, omega_t): forward speed (m/s), yaw rate (rad/s, positive turns left)
    and tilt rate (rad/s, positive looks up); defaults 0.6 m/s, 1.0 rad/s, 1.0 rad/s (all
    within [-1, 1], as Gymnasium's checker recommends).
    The drive turns (v, omega) into wheel speeds v_l,r = v -+ omega D / 2, scales both
    together to ``wheel_speed_max_mps`` and (if set) ``wheel_accel_max_mps2``, and
    optionally quantises them to 8-bit integers in cm/s, rounded down
    (``wheel_quantization``), as the spec's robot does; the tilt stops at
    [``tilt_min_rad``, ``tilt_max_rad``]. The velocity applied after all this is in the
    state and in ``info["applied_action"]``. Finite out-of-range actions are clipped; NaN,
    inf or a wrong shape raise ``ValueError``.

    ## Observation Space
    - ``obs_mode="rgb"`` (default): the latest camera frame, ``Box(0, 255, (240, 320, 3),
      uint8)``. When a frame is dropped, the previous frame is repeated (as a copy).
    - ``obs_mode="state"``: ``Box((15,), float32)``, the ground truth with the layout
      ``observer_gym.envs.target_follower.STATE_NAMES``: the image state
      X_i = (x_i, y_i, d_x) (px; x_i right and y_i up from the principal point, d_x =
      f_x W / z_c), its target-induced rate X_i^t' = J_t V_t (px/s, spec (3)(4)), the
      robot's pose (x, y, yaw), the tilt phi, the applied (v, omega, omega_t),
      ``tracking_valid`` (1: the target is in front of the camera) and ``target_visible``
      (1: on the image and not fully hidden).
    - ``obs_mode="measurements"``: a Dict with what a perfect detector reports for the
      latest frame (no rendering): ``target_px`` (x_i, y_i, d_x) with the spec's noise
      model Z = round(X + sigma_n (2 w - 1)), sigma_n = ``measurement_noise_px``, and
      ``detected`` (0 when the target is outside the image or fully hidden).

    ``env.state_space`` is the Box of the state layout whatever the obs_mode (an
    observer's estimate lives there). ``info`` always holds ``state`` (ground truth,
    unclipped), ``time_s``, ``camera`` (the current ``K``, ``T_world_cam``,
    ``image_size_px``), ``frames`` (the frames delivered this step, empty if dropped, each
    with ``camera_id``, ``capture_time_s``, ``K``, ``T_world_cam``, ``image_size_px``),
    ``calibration`` (f_x, f_y, c_x, c_y, W, delta_y, D, T), ``applied_action``
    (v, omega, omega_t applied over the last step), ``target_pos_world``,
    ``target_vel_world``, ``target_in_image`` and ``occluded`` (the occluder hides it).

    ## Rewards
    ``1 - mean_j min(|e_j| / s_j, 1)`` per step with e = X_i - (0, 0, d*) and
    s = (width / 2, height / 2, d*): 1 with the target centred at the set size, 0 when
    it is off the image.

    ## Starting State
    Robot at the origin facing +x, at rest, tilt 0 (spec Table 1). The target's centre is
    ahead of the camera at a distance uniform in [``start_distance_min_m``,
    ``start_distance_max_m``], a bearing uniform within +-``start_bearing_max_rad`` and a
    height uniform in [``start_height_min_m``, ``start_height_max_m``].
    ``reset(options={"target_pos_world_m": (x, y, z), "tilt_rad": phi,
    "occlusions_s": (t0, ...)})`` sets the target's start, the tilt, and times at which the
    occluder starts walking in (it hides the target 1 s later, for ``occluder_hold_s``).

    Randomness: the start, the target's motion and pushes and the occluder's events come
    from ``np_random`` in the same order whatever the obs_mode and the sensor options, so
    episodes with the same seed and actions see the same world in "state",
    "measurements" and "rgb" and at every latency, drop rate or noise level
    (``observer-gym compare`` and ``sweep`` pair on this). The sensor (frame drops,
    jitters, measurement and image noise) draws from streams spawned from ``np_random``
    at each reset (``Generator.spawn``, which draws nothing from it): ``reset(seed=s)``
    repeats them, a reset without a seed continues with new ones. v0 drew its frame drops
    from ``np_random``, one uniform per step; the env still draws that uniform (and
    discards it), so every seed keeps its v0 episode. ``frame_rate_hz`` is also the
    control rate (one step per frame), so it changes the world's steps.

    ## Episode End
    Terminated when the target has been outside the image for ``lost_timeout_s`` or comes
    closer than ``min_distance_m`` to the camera. Truncated by the registered time limit of
    600 steps (60 s at the default 10 Hz).

    ## Arguments
    ``gym.make("observer_gym/TargetFollower-v0", **options)``; the options are the fields
    of :class:`TargetFollowerConfig` (``TargetFollowerConfig.describe()`` lists them).
    A bad value or an unknown option raises ``ValueError``.

    ## Copies and closing
    ``pickle`` and ``copy.deepcopy`` give an env that steps on exactly as this one: it
    replays the episode's actions in a world of its own (24 B a step, kept for at
    most ``copy_history_max_steps`` steps, 10,000 by default; past them a copy raises
    ``EpisodeTooLongToCopyError`` until the next reset). After ``close()``, ``step``,
    ``render``, ``camera_pose`` and the scene's ground truth raise ``EnvClosedError``
    until ``reset()``, which builds a new world (envs/core.py).

    ## Example
    >>> import gymnasium as gym
    >>> import numpy as np
    >>> import observer_gym.envs
    >>> env = gym.make("observer_gym/TargetFollower-v0")
    >>> frame, info = env.reset(seed=0)
    >>> frame.shape, frame.dtype
    ((240, 320, 3), dtype('uint8'))
    >>> x_px, y_px, width_px = info["state"][:3]  # the target in the image (ground truth)
    >>> bool(20 < width_px < 50)  # a 0.12 m target 1.1-1.7 m away, at fx = 393 px
    True
    >>> frame, reward, terminated, truncated, info = env.step(np.zeros(3, np.float32))
    >>> len(info["frames"])  # one frame per step at the default sensor
    1
    >>> env.close()

    ## Version History
    - v0: initial version; since 2026-11-24 the sensor draws its timing
      (jitters, drops) from a stream of its own, so a seed's world no longer depends on
      them (episodes at the default options are unchanged; with jitter or drops they
      differ from before), and ``reset``'s info gives the declared sensor
      (``info["sensor"]``). Since 2026-11-26 a copy keeps at most
      ``copy_history_max_steps`` actions, a copy right after ``reset`` no longer delivers
      the reset's frames again at its first step, and a closed env raises
      ``EnvClosedError`` instead of PyBullet's "Not connected to physics server" or stale
      data. Since 2026-11-28 options whose nearest start lies within ``min_distance_m``
      (``start_distance_min_m * cos(start_bearing_max_rad) <= min_distance_m``: an
      episode could end at its first step) raise ``ValueError``.
    """

    world_shaping_sensor_options = ("frame_rate_hz",)  # one step per frame
    config_class = TargetFollowerConfig
    suite_knobs = SuiteKnobs(
        disturbed={"push_rate_hz": 2.0, "frame_drop_prob": 0.1, "occluder_rate_hz": 0.2},
        measurement_noise={"measurement_noise_px": 0.5},
        paired={"image_noise_std": 8.0},  # its image size sets the focal length in pixels
    )
    metadata: dict[str, Any] = {"render_modes": ["rgb_array"], "render_fps": 10}  # noqa: RUF012
    clipping_planes_m = (0.05, FAR_PLANE_M)
    # v0 drew one uniform per frame (one frame per step) from np_random for its drop,
    # whatever frame_drop_prob; drawing it still keeps every seed's v0 episode.
    keeps_v0_drop_draw = True

    def __init__(self, render_mode: str | None = None, **options: Any) -> None:
        cfg = TargetFollowerConfig.from_kwargs(**options)
        self.tick_s = cfg.dt_s / cfg.substeps
        self.ticks_per_step = cfg.substeps
        self.metadata = {**self.metadata, "render_fps": cfg.frame_rate_hz}
        self.limits = DriveLimits(
            cfg.wheel_base_m,
            cfg.wheel_speed_max_mps,
            cfg.wheel_accel_max_mps2,
            cfg.wheel_quantization,
        )
        self.occluder_walk = OccluderWalk(cfg.occluder_hold_s, cfg.occluder_rate_hz)
        self._command = np.zeros(3)
        self._lost_s = 0.0
        self._truth: GroundTruth | None = None
        self._calibration: dict[str, float] | None = None
        super().__init__(render_mode, **options)

    @property
    def intrinsics(self) -> PinholeIntrinsics:
        """The camera's nominal calibration."""
        return self.rig.nominal[0]

    @property
    def calibration(self) -> dict[str, float]:
        """What a calibrated rig knows: intrinsics, W, delta_y, D and T (a new dict)."""
        if self._calibration is None:  # made once: the config and the nominal camera are fixed
            self._calibration = self._make_calibration()
        return dict(self._calibration)

    def _make_calibration(self) -> dict[str, float]:
        cfg, intr = self.config, self.intrinsics
        return {
            "fx_px": intr.fx_px,
            "fy_px": intr.fy_px,
            "cx_px": intr.cx_px,
            "cy_px": intr.cy_px,
            "target_width_m": cfg.target_width_m,
            "delta_y_m": cfg.delta_y_m,
            "wheel_base_m": cfg.wheel_base_m,
            "dt_s": cfg.dt_s,
        }

    # --- the system's hooks -------------------------------------------------------------
    def _sensor_spec(self) -> SensorSpec:
        # The spec's noise model, Table 2: sigma_n (2 w - 1) with w ~ U[0, 1] has variance
        # sigma_n^2 / 3; rounding to whole pixels adds 1/12 px^2.
        cfg = self.config
        rounding_px2 = 1.0 / 12.0 if cfg.measurement_rounding else 0.0
        variance = cfg.measurement_noise_px**2 / 3.0 + rounding_px2
        return cfg.sensor_spec(measurement_noise_std_px=math.sqrt(variance))

    def camera_intrinsics(self) -> list[PinholeIntrinsics]:
        cfg = self.config
        w, h = cfg.image_width_px, cfg.image_height_px
        return [PinholeIntrinsics(w, h, cfg.fx_px, cfg.fy_px, w / 2.0, h / 2.0)]

    def _make_action_space(self) -> spaces.Box:
        cfg = self.config
        high = np.array(
            [cfg.max_speed_mps, cfg.max_yaw_rate_radps, cfg.max_tilt_rate_radps], np.float32
        )
        return spaces.Box(-high, high, dtype=np.float32)

    def _make_state_space(self) -> spaces.Box:
        return spaces.Box(
            np.array(STATE_LOW, np.float32), np.array(STATE_HIGH, np.float32), dtype=np.float32
        )

    def _measurement_space(self) -> spaces.Dict:
        cfg = self.config
        w, h = self.rig.image_size_px
        bound = float(max(w, h)) + 2.0 * cfg.measurement_noise_px + 1.0
        d_max = 4.0 * max(w, h)
        return spaces.Dict(
            {
                TARGET_PX: spaces.Box(
                    np.array([-bound, -bound, 0.0], np.float32),
                    np.array([bound, bound, d_max], np.float32),
                ),
                DETECTED: spaces.MultiBinary(1),
            }
        )

    def _empty_measurement(self) -> dict:
        return empty_measurement()

    def _build_world(self, sim: Simulation) -> None:
        cfg = self.config
        self.scene = TargetFollowerScene(
            sim,
            self.intrinsics.K,
            self.rig.image_size_px,
            cfg.target_width_m,
            cfg.delta_y_m,
            (cfg.tilt_min_rad, cfg.tilt_max_rad),
            self.limits,
            with_occluder=True,
        )

    def _reset_options(self) -> tuple[str, ...]:
        return RESET_OPTIONS

    def _checked_reset_options(self, options: dict) -> dict:
        cfg = self.config
        tilt = options.get("tilt_rad", 0.0)
        target = options.get("target_pos_world_m")
        return {
            "tilt_rad": real_number(
                "reset option tilt_rad", tilt, cfg.tilt_min_rad, cfg.tilt_max_rad
            ),
            "occlusions_s": self._checked_occlusions(options.get("occlusions_s", ())),
            "target_pos_world_m": None
            if target is None
            else real_array("reset option target_pos_world_m", target, (3,), TARGET_BOUND_M),
        }

    def _start_episode(self, rng: np.random.Generator, options: dict) -> None:
        cfg = self.config
        tilt = options["tilt_rad"]
        occlusions = options["occlusions_s"]
        distance = rng.uniform(cfg.start_distance_min_m, cfg.start_distance_max_m)
        bearing = rng.uniform(-cfg.start_bearing_max_rad, cfg.start_bearing_max_rad)
        height = rng.uniform(cfg.start_height_min_m, cfg.start_height_max_m)
        target = options.get("target_pos_world_m")
        if target is None:
            eye = geo.camera_pose(np.zeros(2), 0.0, tilt, cfg.delta_y_m)[:3, 3]
            target = np.array(
                [
                    eye[0] + distance * math.cos(bearing),
                    eye[1] + distance * math.sin(bearing),
                    height,
                ]
            )
        motion = TargetMotion(
            cfg.target_motion,
            target,
            rng,
            walk_speed_mps=cfg.walk_speed_mps,
            push_rate_hz=cfg.push_rate_hz,
            push_speed_mps=cfg.push_speed_mps,
            turn_rate_radps=cfg.profile_turn_rate_radps,
        )
        self.scene.start(tilt, motion)
        self.occluder_walk = OccluderWalk(
            cfg.occluder_hold_s, cfg.occluder_rate_hz, tuple(occlusions.tolist())
        )
        self._lost_s = 0.0

    @staticmethod
    def _checked_occlusions(value) -> np.ndarray:
        """Occlusion start times: finite seconds in [0, OCCLUSION_START_MAX_S]."""
        name = "reset option occlusions_s"
        try:
            ndim = np.ndim(value)
        except ValueError:  # ragged nested sequences
            ndim = None
        if ndim != 1:
            raise ValueError(f"{name} must be a sequence of start times in seconds, got {value!r}")
        times = real_array(name, value, (len(value),), OCCLUSION_START_MAX_S)
        if np.any(times < 0.0):
            raise ValueError(f"{name} must be times >= 0 s, got {value!r}")
        return times

    def _apply_action(self, action: np.ndarray) -> None:
        self._command = action

    def _advance(self, end_tick: int) -> None:
        start = self._tick
        assert start is not None, "reset() first"
        if self._next_stop(end_tick) == end_tick:  # no camera captures inside the step
            self.scene.advance(self._command, self.config.dt_s, self.ticks_per_step)
        else:
            self.scene.advance(
                self._command,
                self.config.dt_s,
                self.ticks_per_step,
                stops=lambda k: start + k + 1 == self._next_stop(end_tick),
                on_stop=lambda k: self._reach(start + k + 1, end_tick),
            )
        self._reach(end_tick, end_tick)

    def _after_physics(self) -> None:
        cfg, scene = self.config, self.scene
        if self._tick == 0:  # a new episode: the ground truth is what the real camera sees
            error = self.rig.errors[0] if cfg.has_calibration_error else None
            scene.set_true_camera(
                self.rig.cameras[0].K, None if error is None else error.T_nominal_true
            )
        walk, now = self.occluder_walk, self.time_s
        walk.update(now, cfg.dt_s, self.np_random)
        pose = None  # walk.pose's answer when no event is under way
        if walk.active_start_s is not None:
            assert scene.motion is not None
            pose = walk.pose(now, scene.camera_pose()[:3, 3], scene.motion.pos)
        scene.place_occluder(pose)
        self._truth = scene.ground_truth()

    def camera_pose(self, camera_id: int = 0) -> np.ndarray:
        self._check_open("camera_pose()")
        return self.scene.camera_pose()

    def _measure(self, camera_id: int, K: np.ndarray, T_world_cam: np.ndarray) -> dict:
        cfg = self.config
        assert self.scene.motion is not None, "reset() first"
        out = perfect_measurement(
            K,
            T_world_cam,
            self.rig.image_size_px,
            self.scene.motion.pos,
            cfg.target_width_m,
            occluder=self.scene.occluder_pose,
            noise_px=cfg.measurement_noise_px,
            rounding=cfg.measurement_rounding,
            rng=self.rig.noise_rng,
        )
        space = cast(spaces.Box, cast(spaces.Dict, self.observation_space)[TARGET_PX])
        out[TARGET_PX] = np.clip(out[TARGET_PX], space.low, space.high).astype(np.float32)
        return out

    def _ground_truth_state(self) -> np.ndarray:
        assert self._truth is not None, "reset() first"
        return self._truth.state

    def _reward(self, action: np.ndarray) -> float:
        assert self._truth is not None, "reset() first"
        if not self._truth.in_image:
            return 0.0
        d_star = self.config.desired_width_px
        w, h = self.rig.image_size_px
        x_i, y_i, d_x = self._truth.state[IMAGE].tolist()
        # 1 - mean(minimum(|X_i - (0, 0, d*)| / s, 1)) in floats, as NumPy computes it:
        # minimum keeps NaN, and the mean of three terms sums them in order.
        total = 0.0
        for error, scale in ((x_i - 0.0, w / 2.0), (y_i - 0.0, h / 2.0), (d_x - d_star, d_star)):
            term = abs(error) / scale
            total += term if term < 1.0 or term != term else 1.0
        return 1.0 - total / 3

    def _terminated(self) -> bool:
        """Called once per step: it also advances the time the target has been lost."""
        cfg = self.config
        assert self._truth is not None, "reset() first"
        self._lost_s = 0.0 if self._truth.in_image else self._lost_s + cfg.dt_s
        too_close = self._truth.depth_m < cfg.min_distance_m
        return bool(self._lost_s >= cfg.lost_timeout_s - 1e-9 or too_close)

    def _info(self) -> dict[str, Any]:
        truth, scene = self._truth, self.scene
        assert truth is not None, "reset() first"
        return {
            "camera": {
                "K": self.rig.K_nominal[0].copy(),
                "T_world_cam": scene.camera_pose().copy(),
                "image_size_px": self.rig.image_size_px,
            },
            "calibration": self.calibration,
            "applied_action": scene.applied.copy(),
            "target_pos_world": truth.target_pos_world.copy(),
            "target_vel_world": truth.target_vel_world.copy(),
            "target_in_image": truth.in_image,
            "occluded": truth.occluded,
        }
