"""``observer_gym/BallTable-v0``."""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces

from observer_gym.envs.ball_table import geometry as geo
from observer_gym.envs.ball_table.config import BallTableConfig
from observer_gym.envs.ball_table.disturbances import Disturbances
from observer_gym.envs.ball_table.layout import (
    BALL_POS,
    BALL_PX,
    CORNERS_PX,
    DETECTED,
    STATE_HIGH,
)
from observer_gym.envs.ball_table.measurements import empty_measurement, perfect_measurement
from observer_gym.envs.ball_table.scene import BallTableScene, GroundTruth
from observer_gym.envs.camera import PinholeIntrinsics
from observer_gym.envs.config import real_array
from observer_gym.envs.core import CameraEnv
from observer_gym.envs.sim import Simulation
from observer_gym.envs.suite_knobs import SuiteKnobs
from observer_gym.envs.transforms import norm

RESET_OPTIONS = ("ball_pos_table_m", "ball_vel_table_mps")


class BallTableEnv(CameraEnv):
    """A robot arm holds a square table with a ball rolling on it; keep the ball at the centre.

    ## Description
    The ball-on-tilting-table system of docs/spec/table_ball.md. A KUKA LBR iiwa arm holds a
    0.30 m square table (red top, raised black borders) at its flange; a solid green ball
    of radius 0.025 m rolls on it. A camera above the table (the robot's eye: 320x240 px,
    90 deg horizontal field of view, 50 frames/s) watches. The agent commands the table's
    tilt; the arm tracks the command through inverse kinematics and joint position
    motors running at the physics rate, so the arm's tracking lag is part of the plant:
    with the default gain a 0.05 rad step reaches 63 % in 0.04 s and stays within 5 %
    after 0.10 s, without overshoot (bounds asserted in tests/envs/test_ball_table_physics.py:
    settling <= 0.2 s, steady error <= 1 mrad; figures from
    ``python benchmarks/quality_ball_table.py``). The ball rolls at 5/7 g sin(theta) to
    within 0.1 % on a held incline.

    ## Action Space
    ``Box(-max_tilt_rad, max_tilt_rad, (2,), float32)``: the commanded table tilt
    (tilt_x, tilt_y) in radians, R_home_table = R_x(tilt_x) R_y(tilt_y); positive tilt_y
    lowers the +x edge, positive tilt_x lowers the -y edge. Finite out-of-range actions
    are clipped; NaN, inf or a wrong shape raise ``ValueError``. For SB3, rescale with
    ``gymnasium.wrappers.RescaleAction(env, -1, 1)``.

    ## Observation Space
    - ``obs_mode="rgb"`` (default): the newest delivered camera frame, ``Box(0, 255,
      (240, 320, 3), uint8)`` (a copy; black before the first frame arrives).
    - ``obs_mode="state"``: ``Box((8,), float32)``, the ground truth with the layout
      ``observer_gym.envs.ball_table.STATE_NAMES`` (ball x, y, vx, vy in the table frame;
      tilt angles and rates), clipped to ``STATE_HIGH``.
    - ``obs_mode="measurements"``: a Dict with what a perfect detector reports for the
      newest delivered frame (no rendering): ``table_corners_px`` (u0, v0, ..., u3, v3),
      ``ball_px`` (u, v, radius) and ``detected`` (table, ball) flags; with
      ``measurement_noise_px`` Gaussian noise.

    The camera follows the sensor model shared by every env (observer_gym.envs.sensor):
    by default one frame per step, captured at the end of the step and delivered at once;
    ``frame_phase_s``, ``latency_s``, ``latency_jitter_s``, ``jitter_s`` and
    ``frame_drop_prob`` change when frames are captured and arrive (a step's observation
    is the newest frame delivered by then, captured earlier), and the ``calib_*`` options
    make the real camera differ from the nominal calibration that ``info`` reports.

    ``env.state_space`` is the Box of the state layout whatever the obs_mode (an
    observer's estimate lives there). ``info`` always holds ``state`` (ground truth,
    unclipped), ``time_s``, ``T_world_table`` (4x4), ``camera`` (the nominal ``K``,
    ``T_world_cam`` now, ``image_size_px``), ``push_impulse_ns`` and ``frames``: the frames
    delivered this step (possibly none), each with ``camera_id``, ``capture_time_s``,
    ``delivery_time_s``, the nominal ``K`` and ``T_world_cam`` at the capture, and
    ``image_size_px``; ``info["truth"]["frames"]`` has each frame's true ``K`` and
    ``T_world_cam`` (for analysis only: an observer knows the nominal calibration).

    ## Rewards
    ``1 - d / (L/2 - r) - effort_weight * mean((a / max_tilt_rad)^2)`` per step, with d
    the ball's distance from the table centre: 1 at the centre with no effort, 0 at a
    border.

    ## Starting State
    Arm at home, table level, the ball rolling without slipping from a point uniform in
    the disc of radius ``start_radius_m`` with a speed uniform in [0, ``start_speed_mps``]
    in a uniform direction. ``reset(options={"ball_pos_table_m": (x, y),
    "ball_vel_table_mps": (vx, vy)})`` sets them instead.

    Randomness: the start, the head motion's phases, the pushes and the occluder's passes
    come from ``np_random`` in the same order whatever the obs_mode and the sensor
    options, so episodes with the same seed and actions see the same world in "state",
    "measurements" and "rgb" and at every latency, drop rate, frame rate or noise level
    (``observer-gym compare`` and ``sweep`` pair on this). The sensor (the camera's
    timing: jitters, drops; measurement and image noise; the calibration errors) draws
    from streams spawned from ``np_random`` at each reset (``Generator.spawn``, which
    draws nothing from it): ``reset(seed=s)`` repeats them, a reset without a seed
    continues with new ones.

    ## Episode End
    Terminated when the ball's centre leaves the red square (|x| or |y| > L/2: over a
    border). Truncated by the registered time limit of 500 steps (10 s at the default 50 Hz).

    ## Arguments
    ``gym.make("observer_gym/BallTable-v0", **options)``; the options are the fields of
    :class:`BallTableConfig` (``BallTableConfig.describe()`` lists them with their ranges).
    A bad value or an unknown option raises ``ValueError``.

    ## Copies and closing
    ``pickle`` and ``copy.deepcopy`` give an env that steps on exactly as this one: it
    replays the episode's actions in a world of its own (16 B a step, kept for at
    most ``copy_history_max_steps`` steps, 10,000 by default; past them a copy raises
    ``EpisodeTooLongToCopyError`` until the next reset). After ``close()``, ``step``,
    ``render``, ``camera_pose`` and the scene's ground truth raise ``EnvClosedError``
    until ``reset()``, which builds a new world (envs/core.py).

    ## Example
    >>> import gymnasium as gym
    >>> import numpy as np
    >>> import observer_gym.envs
    >>> env = gym.make("observer_gym/BallTable-v0", obs_mode="state")
    >>> obs, info = env.reset(seed=0, options={"ball_pos_table_m": (0.05, 0.0),
    ...                                        "ball_vel_table_mps": (0.0, 0.0)})
    >>> obs.shape
    (8,)
    >>> for _ in range(25):  # 0.5 s with the +x edge raised by 0.05 rad
    ...     obs, reward, terminated, truncated, info = env.step(np.array([0.0, -0.05], np.float32))
    >>> bool(obs[2] < -0.1)  # the ball rolls towards -x (5/7 g sin 0.05 = 0.35 m/s^2)
    True
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
      data.
    """

    world_shaping_sensor_options = ("frame_rate_hz",)  # one step per frame
    config_class = BallTableConfig
    suite_knobs = SuiteKnobs(
        disturbed={"push_rate_hz": 2.0, "frame_drop_prob": 0.1},
        measurement_noise={"measurement_noise_px": 0.5},
        paired={
            "occluder_rate_hz": 1.0,
            "image_noise_std": 8.0,
            "image_width_px": 80,
            "image_height_px": 60,
        },
    )
    metadata: dict[str, Any] = {"render_modes": ["rgb_array"], "render_fps": 50}  # noqa: RUF012
    clipping_planes_m = (0.05, 3.0)

    def __init__(self, render_mode: str | None = None, **options: Any) -> None:
        cfg = BallTableConfig.from_kwargs(**options)
        self.tick_s = cfg.physics_dt_s
        self.ticks_per_step = cfg.physics_substeps
        self.metadata = {**self.metadata, "render_fps": cfg.frame_rate_hz}
        self.disturbances = Disturbances(cfg)
        self._arm_home_q: np.ndarray | None = None  # IK refines it at the first build; reused
        self._push_impulse: np.ndarray | None = None
        self._truth: GroundTruth | None = None
        self._truth_tick: int | None = -1  # the tick self._truth describes
        super().__init__(render_mode, **options)

    # --- the system's hooks -------------------------------------------------------------
    def camera_intrinsics(self) -> list[PinholeIntrinsics]:
        cfg = self.config
        return [PinholeIntrinsics.from_fov(cfg.image_width_px, cfg.image_height_px, cfg.hfov_deg)]

    def _make_action_space(self) -> spaces.Box:
        tilt = np.full(2, self.config.max_tilt_rad, dtype=np.float32)
        return spaces.Box(-tilt, tilt, dtype=np.float32)

    def _make_state_space(self) -> spaces.Box:
        high = np.array(STATE_HIGH, dtype=np.float32)
        return spaces.Box(-high, high, dtype=np.float32)

    def _measurement_space(self) -> spaces.Dict:
        w, h = self.rig.image_size_px
        uv_high = np.array([w - 1, h - 1], dtype=np.float32)
        return spaces.Dict(
            {
                CORNERS_PX: spaces.Box(np.zeros(8, np.float32), np.tile(uv_high, 4)),
                BALL_PX: spaces.Box(
                    np.zeros(3, np.float32), np.array([w - 1, h - 1, max(w, h)], np.float32)
                ),
                DETECTED: spaces.MultiBinary(2),
            }
        )

    def _empty_measurement(self) -> dict:
        return empty_measurement()

    def _build_world(self, sim: Simulation) -> None:
        self.scene = BallTableScene(
            sim,
            self.config.arm_position_gain,
            with_occluder=self.config.occluder_rate_hz > 0,
            arm_home_q=self._arm_home_q,
        )
        self._arm_home_q = self.scene.arm.home_q

    def _reset_options(self) -> tuple[str, ...]:
        return RESET_OPTIONS

    def _checked_reset_options(self, options: dict) -> dict:
        return {
            name: None if value is None else _checked_ball_option(name, value)
            for name, value in options.items()
        }

    def _start_episode(self, rng: np.random.Generator, options: dict) -> None:
        cfg = self.config
        ball_pos = options.get("ball_pos_table_m")
        ball_vel = options.get("ball_vel_table_mps")
        if ball_pos is None:
            radius = cfg.start_radius_m * np.sqrt(rng.uniform())
            angle = rng.uniform(0.0, 2.0 * np.pi)
            ball_pos = radius * np.array([np.cos(angle), np.sin(angle)])
        if ball_vel is None:
            speed = rng.uniform(0.0, cfg.start_speed_mps)
            angle = rng.uniform(0.0, 2.0 * np.pi)
            ball_vel = speed * np.array([np.cos(angle), np.sin(angle)])
        self.scene.place_ball(ball_pos, ball_vel)
        self.disturbances.reset(rng)
        self._push_impulse = None

    def _apply_action(self, action: np.ndarray) -> None:
        self.scene.command_tilt(float(action[0]), float(action[1]))
        self._push_impulse = self.disturbances.push_impulse(self.np_random)
        if self._push_impulse is not None:
            self.scene.push_ball(self._push_impulse)

    def _after_physics(self) -> None:
        self._truth = self.scene.ground_truth()
        self._truth_tick = self._tick
        occluder_pos = self.disturbances.occluder_position(self.time_s, self.np_random)
        if self.scene.occluder is not None:
            if occluder_pos is None:
                self.scene.park_occluder()
            else:
                self.scene.place_occluder(occluder_pos)

    def camera_pose(self, camera_id: int = 0) -> np.ndarray:
        self._check_open("camera_pose()")
        return self.disturbances.camera_pose(self.time_s)

    def _measure(self, camera_id: int, K: np.ndarray, T_world_cam: np.ndarray) -> dict:
        occluder = None
        if self.scene.occluder_pose_world is not None:
            centre, rotation = self.scene.occluder_pose_world
            occluder = (centre, rotation, geo.OCCLUDER_HALF_EXTENTS_M)
        truth = self._truth if self._truth_tick == self._tick else self.scene.ground_truth()
        assert truth is not None
        return perfect_measurement(
            K,
            T_world_cam,
            self.rig.image_size_px,
            truth.T_world_table,
            truth.ball_pos_world,
            occluder=occluder,
            noise_px=self.config.measurement_noise_px,
            rng=self.rig.noise_rng,
        )

    def _ground_truth_state(self) -> np.ndarray:
        assert self._truth is not None, "reset() first"
        return self._truth.state

    def _reward(self, action: np.ndarray) -> float:
        cfg = self.config
        assert self._truth is not None, "reset() first"
        distance = norm(self._truth.state[BALL_POS])
        # np.mean((action / max_tilt_rad) ** 2) in floats: NumPy sums two terms in order.
        tilt_x, tilt_y = action.tolist()
        tilt_x, tilt_y = tilt_x / cfg.max_tilt_rad, tilt_y / cfg.max_tilt_rad
        effort = (tilt_x * tilt_x + tilt_y * tilt_y) / 2
        return 1.0 - distance / geo.BALL_TRAVEL_M - cfg.effort_weight * effort

    def _terminated(self) -> bool:
        assert self._truth is not None, "reset() first"
        x, y, _ = self._truth.ball_pos_table.tolist()
        if x != x or y != y:  # NaN: np.max gave NaN, never beyond the border
            return False
        return max(abs(x), abs(y)) > geo.TABLE_SIDE_M / 2

    def _info(self) -> dict[str, Any]:
        T_world_cam = self.camera_pose()
        assert self._truth is not None, "reset() first"
        return {
            "T_world_table": self._truth.T_world_table.copy(),
            "camera": {
                "K": self.rig.K_nominal[0].copy(),
                "T_world_cam": T_world_cam.copy(),
                "image_size_px": self.rig.image_size_px,
            },
            "push_impulse_ns": self._push_impulse,
        }


def _checked_ball_option(name: str, value) -> np.ndarray:
    """The reset option ``name`` (a RESET_OPTIONS key) as a float 2-vector, or ValueError."""
    bound = geo.BALL_TRAVEL_M if name == "ball_pos_table_m" else 2.0
    return real_array(f"reset option {name}", value, (2,), bound)
