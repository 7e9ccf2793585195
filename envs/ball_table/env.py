"""``observer_gym/BallTable-v0``."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from observer_gym.envs.actions import checked_action
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
from observer_gym.envs.ball_table.measurements import perfect_measurement
from observer_gym.envs.ball_table.scene import BallTableScene
from observer_gym.envs.camera import Camera, PinholeIntrinsics
from observer_gym.envs.config import check_render_mode
from observer_gym.envs.observations import copy_observation
from observer_gym.envs.sim import Simulation


class BallTableEnv(gym.Env):
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
    - ``obs_mode="rgb"`` (default): the latest camera frame, ``Box(0, 255, (240, 320, 3),
      uint8)``. When a frame is dropped, the previous frame is repeated (as a copy).
    - ``obs_mode="state"``: ``Box((8,), float32)``, the ground truth with the layout
      ``observer_gym.envs.ball_table.STATE_NAMES`` (ball x, y, vx, vy in the table frame;
      tilt angles and rates), clipped to ``STATE_HIGH``.
    - ``obs_mode="measurements"``: a Dict with what a perfect detector reports for the
      latest frame (no rendering): ``table_corners_px`` (u0, v0, ..., u3, v3),
      ``ball_px`` (u, v, radius) and ``detected`` (table, ball) flags; with
      ``measurement_noise_px`` Gaussian noise.

    ``env.state_space`` is the Box of the state layout whatever the obs_mode (an
    observer's estimate lives there). ``info`` always holds ``state`` (ground truth,
    unclipped), ``time_s``,
    ``T_world_table`` (4x4), ``camera`` (the current ``K``, ``T_world_cam``,
    ``image_size_px``) and ``frames``: the frames delivered this step (empty if dropped),
    each with ``camera_id``, ``capture_time_s``, ``K``, ``T_world_cam``, ``image_size_px``.

    ## Rewards
    ``1 - d / (L/2 - r) - effort_weight * mean((a / max_tilt_rad)^2)`` per step, with d
    the ball's distance from the table centre: 1 at the centre with no effort, 0 at a
    border.

    ## Starting State
    Arm at home, table level, the ball rolling without slipping from a point uniform in
    the disc of radius ``start_radius_m`` with a speed uniform in [0, ``start_speed_mps``]
    in a uniform direction. ``reset(options={"ball_pos_table_m": (x, y),
    "ball_vel_table_mps": (vx, vy)})`` sets them instead.

    Randomness: disturbances are drawn from the reset seed identically in every obs_mode;
    sensor noise from its own stream. The start, the head motion's phases, the pushes,
    the occluder's passes and the frame drops come from ``np_random`` in the same order
    whatever the obs_mode, so episodes with the same seed and actions see the same world
    in "state", "measurements" and "rgb" (``observer-gym compare`` pairs on this). The
    measurement noise (``measurement_noise_px``) and image noise (``image_noise_std``)
    come from a generator spawned from ``np_random`` at each reset (``Generator.spawn``,
    which draws nothing from it): ``reset(seed=s)`` repeats the noise, a reset without a
    seed continues with new noise.

    ## Episode End
    Terminated when the ball's centre leaves the red square (|x| or |y| > L/2: over a
    border). Truncated by the registered time limit of 500 steps (10 s at the default 50 Hz).

    ## Arguments
    ``gym.make("observer_gym/BallTable-v0", **options)``; the options are the fields of
    :class:`BallTableConfig` (``BallTableConfig.describe()`` lists them with their ranges).
    A bad value or an unknown option raises ``ValueError``.

    ## Version History
    - v0: initial version.
    """

    metadata: dict[str, Any] = {"render_modes": ["rgb_array"], "render_fps": 50}  # noqa: RUF012

    def __init__(self, render_mode: str | None = None, **options: Any) -> None:
        self.config = BallTableConfig.from_kwargs(**options)
        check_render_mode(render_mode, self.metadata)
        cfg = self.config
        self.render_mode = render_mode
        self.metadata = {**self.metadata, "render_fps": cfg.frame_rate_hz}
        self.intrinsics = PinholeIntrinsics.from_fov(
            cfg.image_width_px, cfg.image_height_px, cfg.hfov_deg
        )
        self._image_size = (cfg.image_width_px, cfg.image_height_px)

        tilt = np.full(2, cfg.max_tilt_rad, dtype=np.float32)
        self.action_space = spaces.Box(-tilt, tilt, dtype=np.float32)
        high = np.array(STATE_HIGH, dtype=np.float32)
        # The space of the ground-truth state (and of an observer's estimate of it).
        self.state_space = spaces.Box(-high, high, dtype=np.float32)
        self.observation_space = self._make_observation_space()

        self.sim = Simulation(cfg.physics_dt_s)
        self._arm_home_q = None  # refined by IK at the first build, reused by the next ones
        self.scene = self._build_scene()  # builds once now, so a broken setup fails here
        self.camera = Camera(self.sim, self.intrinsics, near_m=0.05, far_m=3.0)
        self.disturbances = Disturbances(cfg)
        self._time_s = 0.0
        self._last_obs = None
        self._frame_index = 0
        self._truth = None
        self._sensor_rng: np.random.Generator | None = None  # spawned at each reset

    def _make_observation_space(self) -> spaces.Space:
        cfg = self.config
        w, h = self._image_size
        if cfg.obs_mode == "rgb":
            return spaces.Box(0, 255, (h, w, 3), dtype=np.uint8)
        if cfg.obs_mode == "state":
            return self.state_space
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

    # --- Gymnasium API ----------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        cfg = self.config
        options = dict(options or {})
        rng = self.np_random
        ball_pos = options.pop("ball_pos_table_m", None)
        ball_vel = options.pop("ball_vel_table_mps", None)
        if options:
            raise ValueError(
                f"unknown reset options {sorted(options)}; allowed: ball_pos_table_m, "
                "ball_vel_table_mps"
            )
        if ball_pos is None:
            radius = cfg.start_radius_m * np.sqrt(rng.uniform())
            angle = rng.uniform(0.0, 2.0 * np.pi)
            ball_pos = radius * np.array([np.cos(angle), np.sin(angle)])
        if ball_vel is None:
            speed = rng.uniform(0.0, cfg.start_speed_mps)
            angle = rng.uniform(0.0, 2.0 * np.pi)
            ball_vel = speed * np.array([np.cos(angle), np.sin(angle)])
        ball_pos = self._checked_option("ball_pos_table_m", ball_pos, geo.BALL_TRAVEL_M)
        ball_vel = self._checked_option("ball_vel_table_mps", ball_vel, 2.0)
        # Sensor noise gets its own stream, so the world's draws from np_random are the
        # same in every obs_mode; spawning draws nothing from np_random.
        self._sensor_rng = rng.spawn(1)[0]

        self.sim.clear()
        self.scene = self._build_scene()
        self.scene.place_ball(ball_pos, ball_vel)
        self.disturbances.reset(rng)
        self._time_s = 0.0
        self._frame_index = 0
        self._last_obs = None
        self._truth = self.scene.ground_truth()
        obs, info = self._observe(dropped=False)
        return obs, info

    def step(self, action):
        tilt_cmd = checked_action(action, self.action_space)
        cfg = self.config
        rng = self.np_random
        self.scene.command_tilt(float(tilt_cmd[0]), float(tilt_cmd[1]))
        impulse = self.disturbances.push_impulse(rng)
        if impulse is not None:
            self.scene.push_ball(impulse)
        self.sim.step(cfg.physics_substeps)
        self._time_s += cfg.dt_s
        self._truth = self.scene.ground_truth()

        distance = float(np.linalg.norm(self._truth.state[BALL_POS]))
        effort = float(np.mean((tilt_cmd / cfg.max_tilt_rad) ** 2))
        reward = 1.0 - distance / geo.BALL_TRAVEL_M - cfg.effort_weight * effort
        terminated = bool(np.max(np.abs(self._truth.ball_pos_table[:2])) > geo.TABLE_SIDE_M / 2)

        obs, info = self._observe(dropped=self.disturbances.frame_dropped(rng))
        info["push_impulse_ns"] = impulse
        return obs, reward, terminated, False, info

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        if self.config.obs_mode == "rgb" and self._last_obs is not None:
            return copy_observation(self._last_obs)  # drawing on it leaves the obs as it was
        return self.camera.render(self.disturbances.camera_pose(self._time_s))

    def close(self) -> None:
        if hasattr(self, "sim"):
            self.sim.close()

    # --- internals --------------------------------------------------------------------
    def _build_scene(self) -> BallTableScene:
        scene = BallTableScene(
            self.sim,
            self.config.arm_position_gain,
            with_occluder=self.config.occluder_rate_hz > 0,
            arm_home_q=self._arm_home_q,
        )
        self._arm_home_q = scene.arm.home_q
        return scene

    @staticmethod
    def _checked_option(name: str, value, bound: float) -> np.ndarray:
        v = np.asarray(value, dtype=float)
        if v.shape != (2,) or not np.all(np.isfinite(v)) or np.any(np.abs(v) > bound):
            raise ValueError(
                f"reset option {name} must be 2 finite numbers within +-{bound}, got {value!r}"
            )
        return v

    def _observe(self, dropped: bool):
        """The observation and info after the world reached ``self._time_s``."""
        cfg = self.config
        T_world_cam = self.disturbances.camera_pose(self._time_s)
        occluder_pos = self.disturbances.occluder_position(self._time_s, self.np_random)
        if self.scene.occluder is not None:
            if occluder_pos is None:
                self.scene.park_occluder()
            else:
                self.scene.place_occluder(occluder_pos)
        camera = {
            "K": self.camera.K.copy(),
            "T_world_cam": T_world_cam.copy(),
            "image_size_px": self._image_size,
        }
        frames = []
        if not dropped or self._frame_index == 0:
            frames.append({"camera_id": 0, "capture_time_s": self._time_s, **camera})
            self._last_obs = self._capture(T_world_cam)
            self._frame_index += 1
        truth = self._truth
        info = {
            "state": truth.state.copy(),
            "time_s": self._time_s,
            "T_world_table": truth.T_world_table.copy(),
            "camera": camera,
            "frames": frames,
        }
        if cfg.obs_mode == "state":
            high = self.observation_space.high
            return np.clip(truth.state, -high, high).astype(np.float32), info
        # A copy: a repeated (dropped) frame must not share memory with the one before.
        return copy_observation(self._last_obs), info

    def _capture(self, T_world_cam: np.ndarray):
        """A new frame in the observation's format."""
        cfg = self.config
        if cfg.obs_mode == "state":
            return None
        if cfg.obs_mode == "rgb":
            image = self.camera.render(T_world_cam)
            if cfg.image_noise_std > 0.0:
                noise = self._sensor_rng.normal(0.0, cfg.image_noise_std, image.shape)
                image = np.clip(image + noise, 0, 255).astype(np.uint8)
            return image
        occluder = None
        if self.scene.occluder_pose_world is not None:
            centre, rotation = self.scene.occluder_pose_world
            occluder = (centre, rotation, geo.OCCLUDER_HALF_EXTENTS_M)
        return perfect_measurement(
            self.camera.K,
            T_world_cam,
            self._image_size,
            self._truth.T_world_table,
            self._truth.ball_pos_world,
            occluder=occluder,
            noise_px=cfg.measurement_noise_px,
            rng=self._sensor_rng,
        )
