"""``observer_gym/BallCatcher-v1``."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from gymnasium import spaces

from observer_gym.envs.ball_catcher import geometry as geo
from observer_gym.envs.ball_catcher.camera_presets import preset_timings
from observer_gym.envs.ball_catcher.config import BallCatcherConfig
from observer_gym.envs.ball_catcher.layout import BALL_POS, BALL_VEL, BOX_POS, BOX_VEL, STATE_HIGH
from observer_gym.envs.ball_catcher.scene import BallCatcherScene, GroundTruth, WorldNow
from observer_gym.envs.ball_catcher.throws import (
    MAX_THROW_SPEED_MPS,
    Throw,
    plane_crossing,
    sample_throw,
)
from observer_gym.envs.camera import PinholeIntrinsics, look_at, project_points
from observer_gym.envs.camera_rig import CameraTiming, Frame
from observer_gym.envs.core import CameraEnv
from observer_gym.envs.sensor import SensorSpec
from observer_gym.envs.sim import GRAVITY_MPS2, Simulation
from observer_gym.envs.suite_knobs import SuiteKnobs
from observer_gym.envs.transforms import norm

FLYING, CAUGHT, MISSED = "flying", "caught", "missed"
# Why an episode missed (info["miss_reason"] on a miss; see Episode End), from the catch
# judgement's record: it entered the front face after touching the box (the line before the
# touch or the entry after it outside the clean radius), entered outside the clean radius
# without a touch, touched the box but never entered it, or never touched nor entered it.
RIM_TOUCH, OUTSIDE_CLEAN_RADIUS = "rim_touch", "outside_clean_radius"
BOUNCED_OFF, MISSED_BOX = "bounced_off", "missed_box"
MISS_REASONS = (RIM_TOUCH, OUTSIDE_CLEAN_RADIUS, BOUNCED_OFF, MISSED_BOX)
NO_FRAME_AGE_S = 10.0  # frame age reported for a camera that has delivered nothing yet
PASSED_MARGIN_M = 0.2  # the ball this far behind the box's back plane has passed it
NEAR_M, FAR_M = 0.1, 8.0  # the cameras' clipping planes; nearer points are not seen
VIEWER_POSE = look_at(np.array([1.9, -3.2, 1.9]), np.array([1.9, 0.0, 0.9]))
_WORKSPACE_LOW = geo.WORKSPACE_LOW_WORLD.tolist()
_WORKSPACE_HIGH = geo.WORKSPACE_HIGH_WORLD.tolist()


class BallCatcherEnv(CameraEnv):
    """An arm carries a box with a hole; a ball is thrown; get it through the hole.

    ## Description
    The ball-catching robot of docs/spec/catcher.md. A KUKA LBR iiwa arm carries a box whose
    front face, turned toward the thrower (+x), has a round hole (6 cm by default); a
    ball of diameter 5 cm is thrown at it from about 2.5 m and takes 0.40-0.48 s to arrive.
    A catch is the ball passing through the hole into the box. Cameras beside the flight
    path (two by default, 320x240, 60 deg horizontal field of view, 50 frames/s each) are
    not synchronised: each has its own phase, latency, jitter and frame losses, set by a
    preset. Physics runs at 1 kHz, in substeps near the box for a ball faster than 10 m/s
    (no tunnelling at any throw speed the options allow, see scene.py); the env steps at
    100 Hz.

    ## Action Space
    ``Box(-v_max, v_max, (3,), float32)``: the commanded velocity (m/s, world frame) of
    the hole's centre; the box keeps facing the thrower. The robot profile limits it
    ("paper": |v| <= 0.5 m/s, |dv/dt| <= 13 m/s^2 as in the spec; "fast": 1.5 m/s,
    30 m/s^2): the command is scaled down to |v| <= v_max and the velocity moves toward
    it by at most a_max dt per step. The integrated target is kept in the workspace
    (``geometry.WORKSPACE_LOW_WORLD`` / ``HIGH``: x 0.65-0.75, y +-0.3, z 0.35-0.65 m),
    braking before a face as the profile allows, and reached by exact inverse kinematics
    and the joint position motors (about 2 ms behind the target). NaN, inf or a wrong
    shape raise ``ValueError``.

    ## Observation Space
    - ``obs_mode="rgb"`` (default): a Dict with ``camera_<c>``, camera c's latest
      delivered frame (``Box(0, 255, (240, 320, 3), uint8)``, black before the first), and
      ``frame_age_s`` (N,): the time since each of those frames was captured
      (10 s before the first).
    - ``obs_mode="measurements"``: a Dict with, per camera, the latest delivered frame's
      perfect-detector report (no rendering): ``uv_px`` (2N,): (u_0, v_0, u_1, ...) the
      projected ball centre
      with Gaussian noise of ``measurement_noise_px``, ``detected`` (N,) whether the ball
      was in the image, ``frame_age_s`` (N,).
      With ``hole_measurements=True`` the Dict also holds ``hole_uv_px`` (2N,) and
      ``hole_detected`` (N,): the same report of the hole's centre (the origin of
      ``T_world_box``), as a detector of the box's outline would locate it: its
      projection through the real camera with Gaussian noise of ``measurement_noise_px``
      (drawn from a stream of its own, so the ball's noise is the same with and without
      it), reported whenever it lies inside the image (occlusion is not modelled, as for
      the ball). At the default placement camera 1 has the box in view and camera 0
      does not. A camera that sees both the ball and the hole sees both shifted by its
      own calibration error, so their difference is nearly free of it.
    - ``obs_mode="state"``: ``Box((12,), float32)``, ground truth with the layout
      ``observer_gym.envs.ball_catcher.STATE_NAMES``: ball position, ball velocity, box
      (hole centre) position, box velocity, world frame.

    ``env.state_space`` is the state Box whatever the obs_mode. ``info`` holds ``state``
    (ground truth), ``time_s``, ``T_world_box``, ``box_pos_world_m`` and
    ``box_vel_world_mps`` (the robot's own forward kinematics, known to any controller),
    ``outcome`` ("flying", "caught", "missed"), ``caught``, ``miss_reason`` (on a miss, why:
    one of ``MISS_REASONS``, see Episode End; None otherwise), ``ball_in_flight`` (the ball
    has not touched the box yet: free flight, where a ballistic model holds; NEES and NIS
    are taken over these steps), ``throw`` (launch position and velocity, drag-free
    crossing time and point of the box's home plane, None for a throw that never reaches
    it), ``sensor`` (after a reset: the declared sensor,
    :class:`~observer_gym.envs.sensor.SensorSpec`) and ``frames``: every frame
    delivered this step, in capture-time order, each with ``camera_id``,
    ``capture_time_s``, ``delivery_time_s``, ``K``, ``T_world_cam``, ``image_size_px``
    and, by obs_mode, ``image`` (rgb) or ``uv_px`` ((2,) or None when the ball was not
    in the image; measurements; with ``hole_measurements`` also ``hole_uv_px``, the
    hole's centre likewise). A frame can arrive after a later-captured frame of
    another camera (latency).

    ## Rewards
    +1 on the step of the catch, plus potential-based shaping (Ng, Harada and Russell,
    1999): each step earns ``shaping_weight`` times the decrease of the predicted miss,
    the distance (m) between the hole's centre and the point where the ball, flying on
    without drag, will cross the box's front plane. It keeps its last value once the
    ball no longer flies freely toward the plane: when it moves away from it, and from
    the ball's first touch of the box on (a ball bouncing off the plate has no crossing
    to predict; before this rule its "prediction" swung by up to a metre within a step
    and gave rewards of -8 to one throw in twenty that the agent could not affect).
    The shaping telescopes to ``shaping_weight`` times (first - last predicted miss),
    so it cannot be farmed and ending an episode early earns nothing; a per-step
    penalty instead taught PPO to rush the box forward to end episodes sooner.

    ## Starting State
    The box at its home (0.7, 0, 0.5) m at rest; the ball just launched by a throw from
    ``throws.sample_throw``: from within +-0.1 m of (3.2, 0, 0.55) m, crossing the box's
    home plane within 0.08 m of the hole's home after 0.40-0.48 s (configurable; the
    defaults are reachable by the "paper" profile and arrive 10-30 deg below horizontal,
    flat enough to pass the hole).
    ``reset(options={"throw": (launch_pos_world, launch_vel_world)})`` sets the throw
    (launch within 10 m of the origin, speed at most ``throws.MAX_THROW_SPEED_MPS``, 100 m/s).

    Randomness: the throw and the preset's camera phases and latencies come from
    ``np_random`` in the same order whatever the obs_mode and the sensor options, so
    episodes with the same seed and actions see the same throw and the same frame times
    in "state", "measurements" and "rgb" and at every jitter, drop rate or noise level
    (``observer-gym compare`` and ``sweep`` pair on this). The sensor (capture and
    latency jitter, frame losses, measurement and image noise, calibration errors)
    draws from streams spawned from ``np_random`` at each reset (``Generator.spawn``,
    which draws nothing from it): ``reset(seed=s)`` repeats them, a reset without a seed
    continues with new ones.

    ## Episode End
    The catch is judged geometrically, on the ball's centre between consecutive physics
    (sub)steps in the box's frame. When that segment crosses the front plane inward on
    the box's front face, the ball has entered: a catch if it crossed within the hole's
    radius minus the ball's (0.5 cm of the axis by default: it cleared the hole's circle)
    and, if it touched the box before (a contact with a normal force), the straight line
    it was flying on just before that touch also crossed within that radius; a miss
    otherwise (a rim hit that still rattles in, or a ball through the plate, is no catch).
    A ball deflected by a touch that does not enter flies on.
    Terminated on a catch or on such a miss, and on a miss by the ball's centre falling
    below 0.15 m or getting 0.2 m behind the box's back plane. Truncated by the env's own
    time limit, in seconds (``config.time_limit_s``): the longest flight
    (``flight_time_max_s``) and 1.52 s after it, at least 2 s; in steps
    (``env.max_episode_steps``, rounded up) 200 at the defaults, 1000 at
    ``control_dt_s=0.002``, 452 for flights of up to 3 s. The env truncates itself (it is
    registered without Gymnasium's step limit), also when built without ``gym.make``;
    ``gym.make(..., max_episode_steps=N)`` adds Gymnasium's ``TimeLimit`` of N steps, and
    the shorter limit ends the episode.

    On the step that ends an episode with a miss, ``info["miss_reason"]`` says which part
    of the rule made it one (``MISS_REASONS``; None on every other step and on a catch):
    ``"rim_touch"``, it entered after touching the box (the line it flew on before the
    touch crossed outside the clean radius, or it crossed inside but the entry after the
    touch was outside: a rim hit that rattled in); ``"outside_clean_radius"``, it entered
    without a touch but outside the clean radius; ``"bounced_off"``, it touched the box
    (rim, plate or a wall) and never entered; ``"missed_box"``, it neither touched nor
    entered the box. A crossing that ``observer-gym run`` shows inside the clean radius can
    be a ``rim_touch``: its centre crossed there after the rim deflected it (seeds
    5000-5099 at the benchmark's lab level with kf-measurements and intercept: 71 misses,
    all touches whose line before the touch crossed 5.1-16.2 mm from the axis; the 44
    that rattled in then crossed 0.1-5.9 mm from it).

    ## Arguments
    ``gym.make("observer_gym/BallCatcher-v1", **options)``; the options are the fields of
    :class:`BallCatcherConfig` (``BallCatcherConfig.describe()`` lists them). A bad value
    or an unknown option raises ``ValueError``.

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
    >>> env = gym.make("observer_gym/BallCatcher-v1", obs_mode="state")
    >>> obs, info = env.reset(seed=0)
    >>> obs.shape, bool(info["ball_in_flight"])
    ((12,), True)
    >>> terminated = truncated = False
    >>> while not (terminated or truncated):  # the box held still
    ...     obs, reward, terminated, truncated, info = env.step(np.zeros(3, np.float32))
    >>> info["outcome"]
    'missed'
    >>> env.close()

    ## Version History
    - v1 (after 0.2.0; 0.2.0 ran this code as v0): the shaping stops at the ball's first
      touch of the box (2026-11-23, Rewards); a geometric catch rule (rim grazes that
      rattle in are misses), the episode ends at the crossing, and substeps near the box
      stop fast throws tunnelling through it (2026-11-23). Since 2026-11-24 the sensor
      draws its timing (jitters, drops) from a stream of its own, so a seed's world no
      longer depends on them, and ``reset``'s info gives the declared sensor
      (``info["sensor"]``). Since 2026-11-26 a copy keeps at most
      ``copy_history_max_steps`` actions, a copy right after ``reset`` no longer delivers
      the reset's frames again at its first step, and a closed env raises
      ``EnvClosedError`` instead of PyBullet's "Not connected to physics server" or stale
      data. Since 2026-11-28 the option ``hole_measurements`` (off by default: the
      default observation space is unchanged) reports the hole's pixels, and the step
      that ends a miss says why (``info["miss_reason"]``). Since 2026-11-28 the time
      limit is in seconds and follows the flight times (Episode End): it was 200 steps
      whatever ``control_dt_s``, so at 2 ms steps or flights over 2 s every episode was
      cut before the ball arrived; at the defaults it is the same 200 steps. Launch
      options that put the lowest launch below 0.15 m or the nearest within 0.5 m of
      the box's reach raise ``ValueError``. (docs/envs.md, "Env versions".)
    - v0: initial version (0.1.0); no longer registered: ``gym.make`` raises Gymnasium's
      ``DeprecatedEnv`` naming v1. The git tag ``v0.1.0`` reproduces its results.
    """

    config_class = BallCatcherConfig
    suite_knobs = SuiteKnobs(
        disturbed={"camera_preset": "random_offsets", "jitter_s": 0.002, "frame_drop_prob": 0.1},
        measurement_noise={"measurement_noise_px": 0.5},
        paired={"image_width_px": 80, "image_height_px": 60},
    )
    model_holds_key = "ball_in_flight"
    metadata: dict[str, Any] = {"render_modes": ["rgb_array"], "render_fps": 100}  # noqa: RUF012
    clipping_planes_m = (NEAR_M, FAR_M)

    def __init__(self, render_mode: str | None = None, **options: Any) -> None:
        cfg = BallCatcherConfig.from_kwargs(**options)
        self.max_episode_steps = cfg.max_episode_steps  # the time limit (Episode End)
        self.tick_s = cfg.physics_dt_s
        self.ticks_per_step = cfg.physics_substeps
        self.metadata = {**self.metadata, "render_fps": round(1.0 / cfg.control_dt_s)}
        self.num_cameras = cfg.cameras
        self.camera_poses = [geo.camera_pose(c) for c in range(self.num_cameras)]
        self._arm_home_q: np.ndarray | None = None
        self._box_vel_cmd = np.zeros(3)
        self._outcome = FLYING
        self._throw: Throw | None = None
        self._truth: GroundTruth | None = None
        self._miss_m = 0.0
        # The catch judgement: the world after the last physics (sub)step (the ball's
        # centre and velocity there, box frame, are scene.ball_in_box(it)), whether the
        # line it flew on before first touching the box would have passed cleanly (None:
        # no touch yet), and whether it entered cleanly (None: not entered).
        self._ball_box: WorldNow | None = None
        self._approach_clean: bool | None = None
        self._entered_clean: bool | None = None
        # Whether the ball had touched the box when it entered (read only once it entered).
        self._entered_after_touch = False
        self._hole_noise_rng: np.random.Generator | None = None  # hole_measurements' noise
        super().__init__(render_mode, **options)

    def step(self, action):
        """One env step (Gymnasium's), truncated at the env's time limit (Episode End)."""
        observation, reward, terminated, truncated, info = super().step(action)
        assert self._history is not None  # made by every reset
        if not terminated and self._history.steps >= self.max_episode_steps:
            truncated = True
        return observation, reward, terminated, truncated, info

    # --- the system's hooks -------------------------------------------------------------
    def _sensor_spec(self) -> SensorSpec:
        # random_offsets: each camera's latency is up to one frame period above latency_s.
        cfg = self.config
        spread_s = 1.0 / cfg.frame_rate_hz if cfg.camera_preset == "random_offsets" else 0.0
        return cfg.sensor_spec(latency_spread_s=spread_s)

    def camera_intrinsics(self) -> list[PinholeIntrinsics]:
        cfg = self.config
        intrinsics = PinholeIntrinsics.from_fov(
            cfg.image_width_px, cfg.image_height_px, cfg.hfov_deg
        )
        return [intrinsics] * self.num_cameras

    def _make_action_space(self) -> spaces.Box:
        v_max = np.full(3, self.config.profile.max_speed_mps, dtype=np.float32)
        return spaces.Box(-v_max, v_max, dtype=np.float32)

    def _make_state_space(self) -> spaces.Box:
        high = STATE_HIGH.astype(np.float32)
        return spaces.Box(-high, high, dtype=np.float32)

    def _make_observation_space(self) -> spaces.Space:
        cfg, n = self.config, self.num_cameras
        w, h = self.rig.image_size_px
        age = spaces.Box(0.0, NO_FRAME_AGE_S, (n,), dtype=np.float32)
        if cfg.obs_mode == "rgb":
            images = {f"camera_{c}": spaces.Box(0, 255, (h, w, 3), np.uint8) for c in range(n)}
            return spaces.Dict({**images, "frame_age_s": age})
        if cfg.obs_mode == "state":
            return self.state_space
        uv_high = np.tile(np.array([w - 1, h - 1], dtype=np.float32), n)
        keys: dict[str, spaces.Space] = {
            "uv_px": spaces.Box(np.zeros(2 * n, np.float32), uv_high),
            "detected": spaces.MultiBinary(n),
            "frame_age_s": age,
        }
        if cfg.hole_measurements:
            keys["hole_uv_px"] = spaces.Box(np.zeros(2 * n, np.float32), uv_high)
            keys["hole_detected"] = spaces.MultiBinary(n)
        return spaces.Dict(keys)

    def _build_world(self, sim: Simulation) -> None:
        cfg = self.config
        self.scene = BallCatcherScene(
            sim, cfg.hole_diameter_m, cfg.arm_position_gain, arm_home_q=self._arm_home_q
        )
        self._arm_home_q = self.scene.arm.home_q

    def _reset_options(self) -> tuple[str, ...]:
        return ("throw",)

    def _checked_reset_options(self, options: dict) -> dict:
        given = options.get("throw")
        return {"throw": None if given is None else self._checked_throw(given)}

    def _start_episode(self, rng: np.random.Generator, options: dict) -> None:
        throw = options["throw"]
        if throw is None:
            throw = sample_throw(self.config, rng)
        self.scene.launch_ball(throw.launch_pos_world, throw.launch_vel_world)
        self._ball_box = self.scene.world_now()
        self._approach_clean = self._entered_clean = None
        self._hole_noise_rng = None  # spawned from this episode's noise stream when needed
        self._throw = throw
        self._box_vel_cmd = np.zeros(3)

    def _camera_timings(self, rng: np.random.Generator) -> list[CameraTiming]:
        cfg = self.config
        timings = preset_timings(
            cfg.camera_preset, self.num_cameras, cfg.frame_rate_hz, cfg.latency_s, rng
        )
        if cfg.frame_phase_s == 0.0:
            return timings
        return [CameraTiming(t.phase_s + cfg.frame_phase_s, t.latency_s) for t in timings]

    def _apply_action(self, action: np.ndarray) -> None:
        self._command_box(action)

    def _advance(self, end_tick: int) -> None:
        drag = self.config.air_drag
        assert self._tick is not None, "reset() first"
        while self._tick < end_tick:
            stop = self._next_stop(end_tick)
            ticks = stop - self._tick
            if not drag and not self.scene.may_reach_box(ticks * self.tick_s):
                # Far from the box: no substeps, no contact, no crossing to judge.
                self.sim.step(ticks)
                self._ball_box = self.scene.world_now()  # transformed only if needed
            else:
                for _ in range(ticks):
                    self.scene.step(drag, self._track_ball)
            self._reach(stop, end_tick)

    def _track_ball(self) -> None:
        """After every physics (sub)step: the catch judgement's record (see Episode End)."""
        hole_m = self.config.hole_diameter_m
        p_prev, v_prev = self.scene.ball_in_box(self._ball_box)
        self._ball_box = self.scene.world_now()
        p = self.scene.ball_in_box(self._ball_box)[0]
        if self._approach_clean is None and self.scene.ball_touches_box():
            point = geo.approach_point(p_prev, v_prev)
            self._approach_clean = point is not None and geo.is_clean(point, hole_m)
        if self._entered_clean is None and p_prev[2] >= 0.0 > p[2]:  # front_plane_entry's test
            point = geo.front_plane_entry(p_prev, p)
            if point is not None and geo.on_front_face(point):
                clean = geo.is_clean(point, hole_m)
                self._entered_clean = clean and self._approach_clean is not False
                self._entered_after_touch = self._approach_clean is not None

    def _after_physics(self) -> None:
        self._truth = self.scene.ground_truth()
        if self._tick == 0:
            self._outcome = FLYING
            self._miss_m = 0.0
            self._miss_m = self._miss_distance_m()
        else:
            self._outcome = self._judge()

    def camera_pose(self, camera_id: int) -> np.ndarray:
        self._check_open("camera_pose()")
        return self.camera_poses[camera_id]

    def _measure(self, camera_id: int, K: np.ndarray, T_world_cam: np.ndarray):
        """A perfect detector's report: the ball's projected centre with noise, or None
        when the centre is behind the camera or outside the image; with
        ``hole_measurements``, the pair (ball, hole centre) of such reports."""
        assert self.rig.noise_rng is not None, "reset() first"
        ball = self._report(K, T_world_cam, self.scene.ball_pos_world(), self.rig.noise_rng)
        if not self.config.hole_measurements:
            return ball
        if self._hole_noise_rng is None:  # a stream of its own: the ball's noise unchanged
            self._hole_noise_rng = self.rig.noise_rng.spawn(1)[0]
        hole_world = self.scene.ground_truth().T_world_box[:3, 3]
        return ball, self._report(K, T_world_cam, hole_world, self._hole_noise_rng)

    def _report(
        self, K: np.ndarray, T_world_cam: np.ndarray, point_world: np.ndarray, rng
    ) -> np.ndarray | None:
        """``point_world`` projected through the camera with measurement_noise_px of noise
        from ``rng``; None behind the near plane or outside the image."""
        uv, depth = project_points(K, T_world_cam, np.asarray(point_world)[None])
        uv = uv[0]
        sigma = self.config.measurement_noise_px
        if sigma > 0.0:
            uv = uv + rng.normal(0.0, sigma, 2)
        w, h = self.rig.image_size_px
        if depth[0] <= NEAR_M or not (0 <= uv[0] <= w - 1 and 0 <= uv[1] <= h - 1):
            return None
        return uv

    def _ground_truth_state(self) -> np.ndarray:
        assert self._truth is not None, "reset() first"
        return self._truth.state

    def _reward(self, action: np.ndarray) -> float:
        miss_m = self._miss_distance_m()
        reward = self.config.shaping_weight * (self._miss_m - miss_m)  # potential-based
        self._miss_m = miss_m
        return reward + (1.0 if self._outcome == CAUGHT else 0.0)

    def _terminated(self) -> bool:
        return self._outcome != FLYING

    def _info(self) -> dict[str, Any]:
        truth, throw = self._truth, self._throw
        assert truth is not None and throw is not None, "reset() first"
        return {
            "T_world_box": truth.T_world_box.copy(),
            "box_pos_world_m": truth.state[BOX_POS].copy(),
            "box_vel_world_mps": truth.state[BOX_VEL].copy(),
            "outcome": self._outcome,
            "caught": self._outcome == CAUGHT,
            "miss_reason": self._miss_reason(),
            # No touch of the box yet: the ball is in free flight, where the observers'
            # ballistic model holds (model_holds_key).
            "ball_in_flight": self._approach_clean is None,
            "throw": {
                "launch_pos_world": throw.launch_pos_world.copy(),
                "launch_vel_world": throw.launch_vel_world.copy(),
                "crossing_time_s": throw.crossing_time_s,
                "crossing_pos_world": (
                    None if throw.crossing_pos_world is None else throw.crossing_pos_world.copy()
                ),
            },
        }

    def _frame_info(self, frame: Frame) -> dict[str, Any]:
        mode = self.config.obs_mode
        if mode == "rgb":
            return {"image": frame.payload}
        if mode == "measurements":
            if self.config.hole_measurements:
                ball, hole = frame.payload
                return {"uv_px": ball, "hole_uv_px": hole}
            return {"uv_px": frame.payload}
        return {}

    def _observation(self):
        cfg = self.config
        if cfg.obs_mode == "state":
            return super()._observation()
        now = self.time_s
        latest = self.rig.latest
        ages = np.array(
            [
                NO_FRAME_AGE_S
                if f is None
                else min(now - f.capture_tick * self.tick_s, NO_FRAME_AGE_S)
                for f in latest
            ],
            dtype=np.float32,
        )
        if cfg.obs_mode == "rgb":
            w, h = self.rig.image_size_px
            blank = np.zeros((h, w, 3), np.uint8)
            images = {  # copies: an observation must not share data with another
                f"camera_{c}": blank if f is None else f.payload.copy()
                for c, f in enumerate(latest)
            }
            return {**images, "frame_age_s": ages}
        n = self.num_cameras
        holes = cfg.hole_measurements
        reports = {"": [None] * n, "hole_": [None] * n}
        for c, f in enumerate(latest):
            if f is not None:
                ball, hole = f.payload if holes else (f.payload, None)
                reports[""][c], reports["hole_"][c] = ball, hole
        out: dict[str, np.ndarray] = {}
        for prefix in ("", "hole_") if holes else ("",):
            uv = np.zeros(2 * n, np.float32)
            detected = np.zeros(n, np.int8)
            for c, report in enumerate(reports[prefix]):
                if report is not None:
                    uv[2 * c : 2 * c + 2] = report
                    detected[c] = 1
            out[f"{prefix}uv_px"], out[f"{prefix}detected"] = uv, detected
        return {**out, "frame_age_s": ages}

    def _render_view(self) -> np.ndarray:
        return self.rig.render_view(VIEWER_POSE)

    @staticmethod
    def _checked_throw(given) -> Throw:
        pos: np.ndarray | None
        vel: np.ndarray | None
        try:
            pos, vel = (_real_vector(v) for v in given)
        except (TypeError, ValueError):
            pos = vel = None
        if pos is None or vel is None or pos.shape != (3,) or vel.shape != (3,):
            raise ValueError(
                "reset option throw must be (launch_pos_world, launch_vel_world), two 3-vectors"
            )
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(vel))):
            raise ValueError(f"reset option throw must be finite, got {given!r}")
        speed = float(np.linalg.norm(vel))
        if np.any(np.abs(pos) > 10.0) or speed > MAX_THROW_SPEED_MPS:
            raise ValueError(
                f"reset option throw: position within 10 m and speed <= {MAX_THROW_SPEED_MPS:g}"
                f" m/s, got position {pos.tolist()} and speed {speed:.6g} m/s"
            )
        crossing = plane_crossing(pos, vel, geo.HOLE_HOME_WORLD[0])
        if crossing is None:  # never reaches the plane: no crossing (None, not NaN, so
            return Throw(pos, vel, None, None)  # two equal episodes' infos compare equal)
        return Throw(pos, vel, *crossing)

    def _command_box(self, velocity_cmd: np.ndarray) -> None:
        """Limit the command by the robot profile, integrate it into the hole's target
        (kept in the workspace) and send the arm there."""
        profile, dt = self.config.profile, self.config.control_dt_s
        desired = velocity_cmd.copy()
        speed = norm(desired)
        if speed > profile.max_speed_mps:
            desired *= profile.max_speed_mps / speed
        change = desired - self._box_vel_cmd
        max_change = profile.max_accel_mps2 * dt
        change_m = norm(change)
        if change_m > max_change:
            change *= max_change / change_m
        velocity = self._box_vel_cmd + change
        # Brake for the workspace's faces as the profile allows: along each axis, no faster
        # than the speed that still stops at the face ahead, sqrt(2 a d); then keep the
        # target in the workspace. Per axis in floats: the values NumPy's where, maximum,
        # sqrt and clip give (clip: x if x > low else low, then that if < high else high).
        brake = 2.0 * profile.max_accel_mps2
        velocities, targets = [], []
        for v, current, low, high in zip(
            velocity.tolist(),
            self.scene.hole_target_world.tolist(),
            _WORKSPACE_LOW,
            _WORKSPACE_HIGH,
            strict=True,
        ):
            ahead_m = high - current if v > 0.0 else current - low
            stoppable = math.sqrt(brake * (ahead_m if ahead_m > 0.0 else 0.0))
            v = v if v > -stoppable else -stoppable
            v = v if v < stoppable else stoppable
            target = current + v * dt
            if target < low or target > high:
                v = 0.0
            target = target if target > low else low
            targets.append(target if target < high else high)
            velocities.append(v)
        self._box_vel_cmd = np.array(velocities)
        self.scene.command_hole(np.array(targets))

    def _judge(self) -> str:
        if self._entered_clean is not None:
            return CAUGHT if self._entered_clean else MISSED
        assert self._truth is not None, "reset() first"
        state = self._truth.state
        ball = state[BALL_POS]
        T = self._truth.T_world_box
        ball_box = T[:3, :3].T @ (ball - T[:3, 3])
        passed = ball_box[2] < -geo.BOX_DEPTH_M - PASSED_MARGIN_M
        if ball[2] < geo.MISS_HEIGHT_M or passed:
            return MISSED
        return FLYING

    def _miss_reason(self) -> str | None:
        """Why the episode missed (one of MISS_REASONS), from the record :meth:`_judge`
        judged on; None unless it missed."""
        if self._outcome != MISSED:
            return None
        if self._entered_clean is not None:  # entered the front face, not cleanly
            return RIM_TOUCH if self._entered_after_touch else OUTSIDE_CLEAN_RADIUS
        # fell below MISS_HEIGHT_M or passed the box without entering it
        return BOUNCED_OFF if self._approach_clean is not None else MISSED_BOX

    def _miss_distance_m(self) -> float:
        """Distance between the hole and where the ball will cross its plane (the last
        value once the ball no longer approaches it or has touched the box)."""
        if self._approach_clean is not None:  # touched the box: no free flight to predict
            return self._miss_m
        assert self._truth is not None, "reset() first"
        # plane_crossing(ball_pos, ball_vel, box_x) in floats, the same operations.
        (px, py, pz), (vx, vy, vz), (bx, by, bz) = (
            self._truth.state[index].tolist() for index in (BALL_POS, BALL_VEL, BOX_POS)
        )
        if not vx < 0.0:
            return self._miss_m
        t = (bx - px) / vx
        if t < 0.0:
            return self._miss_m
        y, z = py + vy * t, (pz + vz * t) - 0.5 * GRAVITY_MPS2 * t * t
        return norm(np.array([y - by, z - bz]))


def _real_vector(value) -> np.ndarray:
    """``value`` as a float array; ValueError unless it holds real numbers (complex parts
    were dropped, strings parsed, bools and masked arrays taken before)."""
    if isinstance(value, np.ma.MaskedArray):
        raise ValueError("a masked array")
    raw = np.asarray(value)
    if raw.dtype.kind not in "iuf":
        raise ValueError(f"dtype {raw.dtype}")
    return raw.astype(float)
