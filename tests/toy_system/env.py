"""``toy/PointMass-v0``: a camera above a point mass on a plane; bring it to the origin."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from gymnasium import spaces

from observer_gym.envs.camera import PinholeIntrinsics, look_at, project_points
from observer_gym.envs.config import config_field
from observer_gym.envs.core import CameraEnv
from observer_gym.envs.sensor import SensorConfig
from observer_gym.envs.sim import Simulation
from observer_gym.envs.suite_knobs import SuiteKnobs

STATE_NAMES = ("x_m", "y_m", "vx_mps", "vy_mps")
CAMERA_HEIGHT_M = 0.8
HFOV_DEG = 60.0
BOUND_M = 0.3  # the episode ends when the mass leaves this square
RADIUS_M = 0.03


@dataclass(frozen=True)
class PointMassConfig(SensorConfig):
    """PointMass-v0's options: the camera's sensor model and these."""

    image_width_px: int = config_field(80, "camera image width", low=32, high=640)
    image_height_px: int = config_field(60, "camera image height", low=32, high=480)
    frame_rate_hz: float = config_field(
        20.0, "camera frame rate; one frame and one action per step", low=5.0, high=100.0
    )
    max_accel_mps2: float = config_field(1.0, "bound on the commanded acceleration", low=0.1)
    push_rate_hz: float = config_field(0.0, "mean rate of random velocity kicks", low=0.0)
    push_speed_mps: float = config_field(0.05, "largest kick", low=0.0, high=1.0)


class PointMassEnv(CameraEnv):
    """A camera 0.8 m above a point mass on the plane z = 0; bring the mass to the origin.

    State ``(x_m, y_m, vx_mps, vy_mps)``; action: the acceleration (ax, ay) in m/s^2;
    reward ``1 - distance / 0.3 m``; terminated when ``|x|`` or ``|y|`` exceeds 0.3 m.
    ``obs_mode="measurements"`` gives ``ball_px`` (u, v) and ``detected``.
    """

    config_class = PointMassConfig
    world_shaping_sensor_options = ("frame_rate_hz",)  # one step per frame
    suite_knobs = SuiteKnobs(
        disturbed={"push_rate_hz": 2.0, "frame_drop_prob": 0.1},
        measurement_noise={"measurement_noise_px": 0.5},
        paired={"image_noise_std": 8.0},
    )
    metadata: dict[str, Any] = {"render_modes": ["rgb_array"], "render_fps": 20}  # noqa: RUF012
    clipping_planes_m = (0.05, 2.0)

    def __init__(self, render_mode: str | None = None, **options: Any) -> None:
        cfg = PointMassConfig.from_kwargs(**options)
        self.tick_s = 1.0 / cfg.frame_rate_hz
        self.ticks_per_step = 1
        self._state = np.zeros(4)
        self._accel = np.zeros(2)
        self._body = -1
        super().__init__(render_mode, **options)

    def camera_intrinsics(self) -> list[PinholeIntrinsics]:
        cfg = self.config
        return [PinholeIntrinsics.from_fov(cfg.image_width_px, cfg.image_height_px, HFOV_DEG)]

    def _make_action_space(self) -> spaces.Box:
        bound = np.full(2, self.config.max_accel_mps2, dtype=np.float32)
        return spaces.Box(-bound, bound, dtype=np.float32)

    def _make_state_space(self) -> spaces.Box:
        high = np.array([1.0, 1.0, 5.0, 5.0], dtype=np.float32)
        return spaces.Box(-high, high, dtype=np.float32)

    def _measurement_space(self) -> spaces.Dict:
        w, h = self.rig.image_size_px
        return spaces.Dict(
            {
                "ball_px": spaces.Box(
                    np.zeros(2, np.float32), np.array([w - 1, h - 1], np.float32)
                ),
                "detected": spaces.MultiBinary(1),
            }
        )

    def _empty_measurement(self) -> dict:
        return {"ball_px": np.zeros(2, np.float32), "detected": np.zeros(1, np.int8)}

    def _build_world(self, sim: Simulation) -> None:
        client = sim.client
        visual = client.createVisualShape(
            client.GEOM_SPHERE, radius=RADIUS_M, rgbaColor=[1, 0, 0, 1]
        )
        self._body = client.createMultiBody(baseMass=0.0, baseVisualShapeIndex=visual)

    def _start_episode(self, rng: np.random.Generator, options: dict) -> None:
        radius = 0.15 * np.sqrt(rng.uniform())
        angle = rng.uniform(0.0, 2.0 * np.pi)
        speed = rng.uniform(0.0, 0.1)
        heading = rng.uniform(0.0, 2.0 * np.pi)
        self._state = np.array(
            [
                radius * np.cos(angle),
                radius * np.sin(angle),
                speed * np.cos(heading),
                speed * np.sin(heading),
            ]
        )
        self._accel = np.zeros(2)
        self._place()

    def _apply_action(self, action: np.ndarray) -> None:
        self._accel = action.astype(float)
        if self.np_random.uniform() < self.config.push_rate_hz * self.dt_s:
            kick = self.config.push_speed_mps * np.sqrt(self.np_random.uniform())
            angle = self.np_random.uniform(0.0, 2.0 * np.pi)
            self._state[2:] += kick * np.array([np.cos(angle), np.sin(angle)])

    def _advance(self, end_tick: int) -> None:
        # p += v dt + a dt^2 / 2; v += a dt (the exact double integrator over the step)
        dt = self.dt_s
        self._state[:2] += self._state[2:] * dt + 0.5 * self._accel * dt * dt
        self._state[2:] += self._accel * dt
        self._place()
        super()._advance(end_tick)

    def _place(self) -> None:
        position = [float(self._state[0]), float(self._state[1]), 0.0]
        self.sim.client.resetBasePositionAndOrientation(self._body, position, [0, 0, 0, 1])
        self.sim.touch()

    def camera_pose(self, camera_id: int = 0) -> np.ndarray:
        return look_at([0.0, 0.0, CAMERA_HEIGHT_M], [0.0, 0.0, 0.0], up_world=(0.0, 1.0, 0.0))

    def _measure(self, camera_id: int, K: np.ndarray, T_world_cam: np.ndarray) -> dict:
        position = np.array([[self._state[0], self._state[1], 0.0]])
        uv, _ = project_points(K, T_world_cam, position)
        uv = uv[0] + self.config.measurement_noise_px * self.rig.noise_rng.standard_normal(2)
        w, h = self.rig.image_size_px
        seen = 0 <= uv[0] <= w - 1 and 0 <= uv[1] <= h - 1
        return {
            "ball_px": (uv if seen else np.zeros(2)).astype(np.float32),
            "detected": np.array([int(seen)], np.int8),
        }

    def _ground_truth_state(self) -> np.ndarray:
        return self._state

    def _reward(self, action: np.ndarray) -> float:
        return 1.0 - float(np.hypot(*self._state[:2])) / BOUND_M

    def _terminated(self) -> bool:
        return bool(np.max(np.abs(self._state[:2])) > BOUND_M)

    def _info(self) -> dict[str, Any]:
        return {
            "camera": {
                "K": self.rig.K_nominal[0].copy(),
                "T_world_cam": self.camera_pose(),
                "image_size_px": self.rig.image_size_px,
            }
        }
