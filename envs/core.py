"""The base of every observer-gym env: one owner of the world, the cameras and the API.

:class:`CameraEnv` owns the :class:`~observer_gym.envs.sim.Simulation` (one DIRECT client
per env), the :class:`~observer_gym.envs.camera_rig.CameraRig` (the sensor model of every
camera), the observation spaces per ``obs_mode``, and Gymnasium's ``reset``, ``step``,
``render`` and ``close``. A system supplies only its hooks: building its scene, starting
an episode, applying an action, advancing the physics, its ground truth, reward and
termination, its cameras' poses and its perfect measurement. A concrete env is the
wiring of those hooks (envs/ball_table/env.py, envs/ball_catcher/env.py,
envs/target_follower/env.py).

One env step, in this order (the random draws of the world come from ``np_random`` in
this order in every obs_mode, so a seed gives the same world whatever the agent observes;
the sensor draws from streams of its own, so the world is also the same whatever the
sensor options, envs/sensor.py):

1. ``_apply_action(action)`` (the action already checked and clipped);
2. ``_advance(end_tick)``: the physics of one step, stopping at every inner tick where a
   camera captures (``_next_stop``, ``_reach``) and running the ticks between in one go;
3. the frames of the step's last tick are decided (drops drawn from the sensor's stream),
   then
   ``_after_physics()`` updates what changes once a step (occluders, ground truth), then
   those frames are captured;
4. frames due by the end of the step are delivered; the observation is the newest
   delivered frame of each camera (a copy), ``info["frames"]`` lists the delivered ones.

Copies: ``pickle`` and ``copy.deepcopy`` give an independent env with its own client,
rebuilt from the config and replayed from the current episode's start (the generator's
state at that reset, its options and the actions since), so it steps on exactly as the
original does. Only a replay gives that: PyBullet's ``saveState``/``restoreState`` and
``saveBullet`` restore the bodies' poses, velocities, joint states and contact points,
but a restored world, even one rebuilt alike, steps on differently from the original:
on BallTable states by 1e-16 to 1e-13 on some, on others by 0.3 mm in the ball's position
and 0.48 rad/s in its spin one step on (benchmarks/bench_copies.py). So the episode's
actions are kept, in one float64 array (the action's bytes per step: 16 B for BallTable, 24 B for
BallCatcher and TargetFollower), for at most ``copy_history_max_steps`` steps (10,000 by
default: the size of a copy stays under that many actions, and its replay under that
many steps). Past it the episode goes on but keeps no more actions, and copying the env
raises :class:`EpisodeTooLongToCopyError` until the next ``reset``. A copy costs the
replay's time: about as long as stepping the env that many steps again
(benchmarks/bench_copies.py).

Closing: ``close()`` disconnects the world; from then on ``step``, ``render``,
``camera_pose`` and every read of the world (the scene's ground truth) raise
:class:`~observer_gym.envs.sim.EnvClosedError` (a ``gymnasium.error.ClosedEnvironmentError``
and a ``RuntimeError``) until ``reset()``, which builds a new world (as SB3's
``check_env`` expects: it closes the env after its render check). A copy of a closed env
is closed too.
"""

from __future__ import annotations

import copy
import dataclasses
import pickle
from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.error import ResetNeeded

from observer_gym.envs.actions import BoxBounds, checked_action
from observer_gym.envs.camera import PinholeIntrinsics
from observer_gym.envs.camera_rig import CameraRig, CameraTiming, Frame
from observer_gym.envs.config import check_render_mode
from observer_gym.envs.observations import copy_observation
from observer_gym.envs.sensor import SensorConfig, SensorSpec
from observer_gym.envs.sim import Simulation

DEFAULT_COPY_HISTORY_MAX_STEPS = 10_000


class EpisodeTooLongToCopyError(pickle.PicklingError):
    """A copy (``pickle``, ``copy.deepcopy``) of an env whose episode has run past its
    ``copy_history_max_steps``: the actions a copy would replay were not kept."""


class ActionHistory:
    """The actions of an episode since its reset, at most ``max_steps`` of them, in one
    float64 array (the actions as applied, after the checks: a copy replays exactly
    those) that doubles as it fills (``shape``: the action space's).

    Past ``max_steps`` it keeps counting the steps but no more actions
    (:attr:`is_complete` turns False).
    """

    INITIAL_CAPACITY_STEPS = 64

    def __init__(self, max_steps: int, shape: tuple[int, ...]) -> None:
        self.max_steps = max_steps
        self.steps = 0
        capacity = min(self.INITIAL_CAPACITY_STEPS, max_steps)
        self._actions = np.empty((capacity, *shape), dtype=np.float64)

    @property
    def is_complete(self) -> bool:
        """Whether every action since the reset is kept."""
        return self.steps <= self.max_steps

    @property
    def nbytes(self) -> int:
        """The bytes the kept actions' array holds (its capacity)."""
        return self._actions.nbytes

    def append(self, action: np.ndarray) -> None:
        steps = self.steps
        self.steps = steps + 1
        if steps >= self.max_steps:
            return
        if steps == len(self._actions):
            grown = np.empty(
                (min(2 * steps, self.max_steps), *self._actions.shape[1:]), self._actions.dtype
            )
            grown[:steps] = self._actions
            self._actions = grown
        self._actions[steps] = action

    def actions(self) -> np.ndarray:
        """The kept actions, one row per step (a view)."""
        return self._actions[: min(self.steps, self.max_steps)]


class CameraEnv(gym.Env):
    """A PyBullet world watched by cameras (see the module docstring).

    Subclasses set ``config_class`` and call ``super().__init__`` with their cameras.

    Args:
        render_mode: None or "rgb_array".
        options: the fields of ``config_class``.
    """

    config_class: type[SensorConfig] = SensorConfig
    metadata: dict[str, Any] = {"render_modes": ["rgb_array"], "render_fps": 50}  # noqa: RUF012
    # Draw one uniform from np_random per step, before _after_physics, and discard it: where
    # v0 of an env drew its frame drops from the world's generator (one per frame, one
    # frame per step), this keeps v0's seeds' episodes now that drops have their own stream.
    keeps_v0_drop_draw: bool = False
    # Sensor options that are also part of the world's dynamics (a frame rate that is the
    # control rate): varying one of them changes the world; varying any other does not.
    world_shaping_sensor_options: tuple[str, ...] = ()
    # The info key (a bool per step) marking the steps where the observers' process model
    # holds, so that NEES and NIS are taken over those steps only (None: every step).
    model_holds_key: str | None = None
    # The most steps of an episode a copy can replay (the module docstring); set on an
    # instance, it applies from the next reset.
    copy_history_max_steps: int = DEFAULT_COPY_HISTORY_MAX_STEPS

    def __init__(self, render_mode: str | None = None, **options: Any) -> None:
        self.config = self.config_class.from_kwargs(**options)
        check_render_mode(render_mode, self.metadata)
        self.render_mode = render_mode
        # (np_random before the episode's first draw, reset options) and the actions
        # since: what a copy replays.
        self._episode: tuple[np.random.Generator, dict] | None = None
        self._history: ActionHistory | None = None
        self._tick: int | None = None  # None until the first reset
        # id(space) -> the bounds of the action and state Boxes, made once per space
        # object (see _bounds).
        self._bounds_cache: dict[int, BoxBounds] = {}
        self.sim = Simulation(self.tick_s)
        self.rig = CameraRig(
            self.sim, self.camera_intrinsics(), self.config, *self.clipping_planes_m
        )
        self.sensor_spec = self._sensor_spec()
        self.action_space = self._make_action_space()
        self.state_space = self._make_state_space()
        self.observation_space = self._make_observation_space()
        self._build_world(self.sim)  # builds once now, so a broken setup fails here

    action_space: spaces.Box  # narrower than gym.Env's Space
    observation_space: spaces.Space
    state_space: spaces.Box

    # --- what a system defines ------------------------------------------------------------
    tick_s: float  # the physics step
    ticks_per_step: int
    clipping_planes_m: tuple[float, float] = (0.05, 5.0)

    def camera_intrinsics(self) -> list[PinholeIntrinsics]:
        """Each camera's nominal calibration."""
        raise NotImplementedError

    def _make_action_space(self) -> spaces.Box:
        raise NotImplementedError

    def _make_state_space(self) -> spaces.Box:
        raise NotImplementedError

    def _measurement_space(self) -> spaces.Space:
        """The observation space of ``obs_mode="measurements"`` (one camera)."""
        raise NotImplementedError

    def _empty_measurement(self) -> Any:
        """The measurements observation before any frame has arrived."""
        raise NotImplementedError

    def _build_world(self, sim: Simulation) -> None:
        """Build the scene in the empty world ``sim``."""
        raise NotImplementedError

    def _start_episode(self, rng: np.random.Generator, options: dict) -> None:
        """Place the world for a new episode (options already checked for unknown keys)."""
        raise NotImplementedError

    def _reset_options(self) -> tuple[str, ...]:
        """The keys ``reset(options=...)`` takes."""
        return ()

    def _checked_reset_options(self, options: dict) -> dict:
        """The reset options as ``_start_episode`` takes them (numbers as floats and
        arrays), or ValueError naming a bad value; called before the reset changes
        anything."""
        return options

    def _sensor_spec(self) -> SensorSpec:
        """The declared sensor (``config.sensor_spec()``; a system with its own pixel-noise
        model or camera timings overrides the entries it computes)."""
        return self.config.sensor_spec()

    def _camera_timings(self, rng: np.random.Generator) -> list[CameraTiming]:
        """Each camera's phase and latency for the episode."""
        return self.rig.default_timings()

    def _apply_action(self, action: np.ndarray) -> None:
        raise NotImplementedError

    def _advance(self, end_tick: int) -> None:
        """The physics of one env step, up to ``end_tick``: run the ticks up to each
        :meth:`_next_stop` and call :meth:`_reach` there (captures on inner ticks)."""
        assert self._tick is not None, "reset() first"
        while self._tick < end_tick:
            stop = self._next_stop(end_tick)
            self.sim.step(stop - self._tick)
            self._reach(stop, end_tick)

    def _after_physics(self) -> None:
        """What changes once per step, before the step's last frames are captured (and
        at reset, before the first)."""

    def camera_pose(self, camera_id: int) -> np.ndarray:
        """Camera ``camera_id``'s nominal ``T_world_cam`` now."""
        raise NotImplementedError

    def _measure(self, camera_id: int, K: np.ndarray, T_world_cam: np.ndarray) -> Any:
        """The perfect detector's report of the world now through the camera (K,
        T_world_cam), noise from ``self.rig.noise_rng``."""
        raise NotImplementedError

    def _ground_truth_state(self) -> np.ndarray:
        raise NotImplementedError

    def _reward(self, action: np.ndarray) -> float:
        raise NotImplementedError

    def _terminated(self) -> bool:
        raise NotImplementedError

    def _info(self) -> dict[str, Any]:
        """The system's own ``info`` entries (``state`` and the frames are added)."""
        return {}

    def _frame_info(self, frame: Frame) -> dict[str, Any]:
        """The system's own entries of a delivered frame's info."""
        return {}

    # --- time -----------------------------------------------------------------------------
    @property
    def dt_s(self) -> float:
        return self.tick_s * self.ticks_per_step

    @property
    def time_s(self) -> float:
        return (self._tick or 0) * self.tick_s

    # --- spaces and observations ----------------------------------------------------------
    def _make_observation_space(self) -> spaces.Space:
        mode = self.config.obs_mode
        if mode == "state":
            return self.state_space
        if mode == "rgb":
            w, h = self.rig.image_size_px
            return spaces.Box(0, 255, (h, w, 3), dtype=np.uint8)
        return self._measurement_space()

    def _bounds(self, space: spaces.Box) -> BoxBounds:
        """``BoxBounds(space)``, kept while ``space`` is the same object."""
        bounds = self._bounds_cache.get(id(space))
        if bounds is None or bounds.space is not space:
            bounds = self._bounds_cache[id(space)] = BoxBounds(space)
        return bounds

    def _observation(self) -> Any:
        """The newest delivered frame (a copy), or the clipped ground truth."""
        mode = self.config.obs_mode
        if mode == "state":
            # np.clip(state, low, high) without its dispatch (the bounds are float64 already).
            bounds = self._bounds(self.state_space)
            clipped = np.maximum(self._ground_truth_state(), bounds.low)
            return np.minimum(clipped, bounds.high, out=clipped).astype(np.float32)
        latest = self.rig.latest[0]
        if latest is not None:
            return copy_observation(latest.payload)
        if mode == "rgb":
            return np.zeros(self.observation_space.shape, np.uint8)
        return self._empty_measurement()

    # --- Gymnasium API --------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        # Checked before anything changes: a refused reset leaves the world, the episode
        # and np_random as they were.
        if options is not None and not isinstance(options, Mapping):
            raise ValueError(
                f"reset options must be a dict (or None), got {type(options).__name__}: "
                f"{options!r}; allowed keys: {', '.join(self._reset_options()) or 'none'}"
            )
        options = dict(options or {})
        unknown = sorted(set(options) - set(self._reset_options()), key=repr)  # keys: any type
        if unknown:
            allowed = ", ".join(self._reset_options()) or "none"
            raise ValueError(f"unknown reset options {unknown}; allowed: {allowed}")
        options = self._checked_reset_options(options)
        history_max_steps = self._checked_copy_history_max_steps()
        super().reset(seed=seed)
        generator = copy.deepcopy(self.np_random)  # before this episode's first draw
        self._begin_episode(options)
        self._episode = (generator, copy.deepcopy(options))
        space = self.action_space
        self._history = ActionHistory(history_max_steps, space.shape)
        delivered = self.rig.deliver(0)
        return self._observation(), {**self._step_info(delivered), "sensor": self.sensor_spec}

    def _checked_copy_history_max_steps(self) -> int:
        value = self.copy_history_max_steps
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
            raise ValueError(f"copy_history_max_steps must be an int >= 0 (steps), got {value!r}")
        return int(value)

    def _begin_episode(self, options: dict) -> None:
        rng = self.np_random
        if not self.sim.is_connected:  # reset after close: a new world
            self.sim = Simulation(self.tick_s)
        self.sim.clear()
        self._build_world(self.sim)
        self._start_episode(rng, options)
        self.rig.reset(self.sim, rng, self._camera_timings(rng))
        self._tick = 0
        due = self.rig.due(0)
        self._after_physics()
        self._capture(due)

    def _check_open(self, call: str) -> None:
        """EnvClosedError naming ``call`` if ``close()`` came after the last reset."""
        self.sim.check_open(call)

    def step(self, action):
        self._check_open("step()")
        if self._tick is None:
            raise ResetNeeded("call reset() before step()")
        space = self.action_space
        action = checked_action(action, space, self._bounds(space))
        assert self._history is not None  # made by every reset, as _tick
        self._history.append(action)
        self._apply_action(action)
        end_tick = self._tick + self.ticks_per_step
        self._advance(end_tick)
        due = self.rig.due(self._tick)
        if self.keeps_v0_drop_draw:
            self.np_random.random()
        self._after_physics()
        self._capture(due)
        reward = float(self._reward(action))
        terminated = bool(self._terminated())
        delivered = self.rig.deliver(self._tick)
        info = self._step_info(delivered, action)
        return self._observation(), reward, terminated, False, info

    def _next_stop(self, end_tick: int) -> int:
        """The next tick the physics must stop at: a camera's capture before
        ``end_tick``, else ``end_tick``."""
        capture = self.rig.next_capture_tick()
        assert self._tick is not None, "reset() first"
        return capture if self._tick < capture < end_tick else end_tick

    def _reach(self, tick: int, end_tick: int) -> None:
        """The world has reached ``tick``: capture the frames due there (the step's last
        tick captures after :meth:`_after_physics`)."""
        self._tick = tick
        if tick < end_tick:
            self._capture(self.rig.due(tick))

    def _capture(self, cameras: list[int]) -> None:
        if cameras:
            assert self._tick is not None, "reset() first"
            self.rig.capture(cameras, self._tick, self.camera_pose, self._measure)

    def _step_info(
        self, delivered: list[Frame], applied: np.ndarray | None = None
    ) -> dict[str, Any]:
        frames, truth = [], []
        now, tick_s = self.time_s, self.tick_s
        for f in delivered:  # copies: an info shares nothing with another (Gymnasium's check)
            info = {
                "camera_id": f.camera_id,
                "capture_time_s": f.capture_tick * tick_s,
                "delivery_time_s": now,
                "K": f.K.copy(),
                "T_world_cam": f.T_world_cam.copy(),
                "image_size_px": self.rig.image_size_px,
                **self._frame_info(f),
            }
            frames.append(info)
            truth.append(
                {"camera_id": f.camera_id, "K": f.K_true, "T_world_cam": f.T_world_cam_true}
            )
        return {
            "state": self._ground_truth_state().copy(),
            "time_s": now,
            # The action this step applied, after clipping (None after a reset); an
            # observer reads it here, so wrappers that rescale actions cannot fool it.
            "applied_action": None if applied is None else applied.copy(),
            **self._info(),
            "frames": frames,
            "truth": {"frames": truth},
        }

    def render(self):
        self._check_open("render()")
        if self.render_mode != "rgb_array":
            return None
        latest = self.rig.latest[0]
        if self.config.obs_mode == "rgb" and latest is not None:
            return latest.payload.copy()  # drawing on it leaves the observation as it was
        return self._render_view()

    def _render_view(self) -> np.ndarray:
        """What ``render()`` shows when it does not repeat the last frame."""
        return self.rig.render_view(self.rig.errors[0].true_pose(self.camera_pose(0)))

    def close(self) -> None:
        if hasattr(self, "sim"):
            self.sim.close()

    # --- copies ---------------------------------------------------------------------------
    def __getstate__(self) -> dict[str, Any]:
        state: dict[str, Any] = {
            "render_mode": self.render_mode,
            "config": dataclasses.asdict(self.config),
            "copy_history_max_steps": self.copy_history_max_steps,
            "np_random": copy.deepcopy(self.np_random),  # made now if never used
            "spec": self.spec,
            "closed": self.sim.is_closed,
            "episode": None,
        }
        if self._history is None or self.sim.is_closed:
            return state
        history = self._history
        if not history.is_complete:
            raise EpisodeTooLongToCopyError(
                f"cannot copy this env: its episode is at step {history.steps}, past "
                f"copy_history_max_steps={history.max_steps} (a copy replays the episode "
                "from its reset, and the env keeps no more actions than that); copy it "
                "earlier in the episode, after a reset(), or set "
                "env.unwrapped.copy_history_max_steps higher before the reset"
            )
        state["episode"] = copy.deepcopy(self._episode)
        state["history_max_steps"] = history.max_steps
        state["actions"] = history.actions().copy()
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        type(self).__init__(self, render_mode=state["render_mode"], **state["config"])
        self.spec = state["spec"]
        if state["copy_history_max_steps"] != type(self).copy_history_max_steps:
            self.copy_history_max_steps = state["copy_history_max_steps"]
        if state["closed"]:
            self.close()
        if state["episode"] is None:
            self.np_random = state["np_random"]
            return
        # The replay leaves np_random where the original's is, and the world's parts
        # that keep a reference to it (TargetFollower's target motion) hold this one.
        generator, options = state["episode"]
        self.np_random = copy.deepcopy(generator)
        self._begin_episode(copy.deepcopy(options))
        self.rig.deliver(0)  # as reset() does: the frames due at once are no longer pending
        self._episode = state["episode"]
        space = self.action_space
        self._history = ActionHistory(state["history_max_steps"], space.shape)
        for action in state["actions"]:
            self.step(action)
