"""One closed-loop episode, and many: what ``run``, ``compare`` and ``sweep`` run.

:class:`EpisodeSpec` is everything one episode needs, resolved: the system's record and
the observer's and controller's entries (strings and dicts, so the spec pickles to a
worker process or a Ray task, which looks no name up again); :func:`run_episode` builds
its own env and controller,
resets with the spec's seed and closes the env, so any episode can be rerun alone and
running the episodes in several processes gives exactly the results of one
(:func:`iter_episodes`, :func:`run_episodes`). :func:`check_entries` tries an outside
observer or controller once before anything runs.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import multiprocessing
import sys
from collections.abc import Callable, Generator, Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from observer_gym.controllers import controllers_of, design_controller
from observer_gym.envs import System, system_for_id
from observer_gym.train.core import entries
from observer_gym.train.core.controller_entries import (
    CheckedController,
    PolicyFile,
)
from observer_gym.train.core.observer_env import ObserverEntry, make_env, resolve_observer
from observer_gym.train.experiments.request import ControllerEntry, resolve_controller
from observer_gym.train.reports.consistency import (
    nees_per_step,
)
from observer_gym.train.reports.outputs import (
    to_jsonable,
)
from observer_gym.train.reports.parent_watch import end_with_parent
from observer_gym.train.reports.progress import progress_bar
from observer_gym.train.reports.rerun_recording import RerunRequest
from observer_gym.train.reports.video import EpisodeVideo, VideoRequest
from observer_gym.train.rl.agent import Agent
from observer_gym.train.rl.run_dir import parse_agent_spec

# Controller attributes recorded in results.json when present (the MPC's Q, R, K are its
# LQR's: its terminal cost and fallback).
CONTROLLER_ATTRIBUTES = (
    "K",
    "Q",
    "R",
    "horizon",
    "constrained",
    "tilt_limit_rad",
    "tilt_rate_limit_radps",
    "ball_limit_m",
    "bounds",  # a generic MPC's constraints (StageBound rows)
    "settings",
    "kp",
    "ki",
    "kd",
    "profile",
    "max_speed_mps",
    "max_accel_mps2",
    "algo",
    "run_dir",
    "obs",
    "timesteps",
    "entry",
)


@dataclasses.dataclass(frozen=True)
class EpisodeSpec:
    """Everything one episode needs, resolved once where the request starts; picklable,
    so a worker process or a Ray task runs it without looking a name up."""

    system: System
    observer: ObserverEntry  # with its options
    controller: ControllerEntry  # with its options
    seed: int
    max_steps: int | None = None
    env_kwargs: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    reset_options: Mapping[str, Any] | None = None
    # the observer and controller if given as Python objects (entries.as_name), by name:
    # they travel with the spec to a worker
    objects: Mapping[tuple[str, str], Any] = dataclasses.field(default_factory=dict)
    # where this episode's video goes (observer_gym.train.reports.video), None for none;
    # the video only reads what the episode produces, so the record is the same
    video: VideoRequest | None = None
    # where this episode's rerun recording goes (observer_gym.train.reports.rerun_recording),
    # None for none; like the video it only reads what the episode produces
    rerun: RerunRequest | None = None

    @property
    def env_id(self) -> str:
        return self.system.env_id

    @classmethod
    def of_entries(
        cls,
        system: System,
        observer: ObserverEntry,
        controller: ControllerEntry,
        seed: int,
        **fields: Any,
    ) -> EpisodeSpec:
        """The spec with the objects the observer and controller names stand for, if any."""
        return cls(
            system, observer, controller, seed, **fields,
            objects=entries.objects_for(observer.name, controller.name),
        )  # fmt: skip

    @classmethod
    def of(
        cls,
        env_id: str,
        observer: str,
        controller: str,
        seed: int,
        observer_options: Mapping[str, Any] | None = None,
        controller_options: Mapping[str, Any] | None = None,
        **fields: Any,
    ) -> EpisodeSpec:
        """The spec of an episode given by names (``observer_options`` over the
        observer's pipeline's or to its factory, ``controller_options`` to the
        controller's constructor or factory): each resolved once here, then
        :meth:`of_entries`."""
        system = system_for_id(env_id)
        return cls.of_entries(
            system,
            resolve_observer(system, observer, observer_options),
            resolve_controller(system, controller, controller_options),
            seed,
            **fields,
        )


class EpisodeError(ValueError):
    """An episode that failed part-way (an observer's or a controller's fault): the
    message names it, the episode's seed and the step."""


def is_outside(observer: ObserverEntry, controller: ControllerEntry) -> bool:
    """Whether the pair has an outside observer or controller (an import path, an entry
    point, or a stable-baselines3 zip): what :func:`check_entries` tries."""
    return observer.plugin is not None or controller.kind in ("outside", "policy")


def entry_identities(
    observer: ObserverEntry, controller: ControllerEntry
) -> dict[str, dict[str, Any]]:
    """Where the pair's outside observer and controller come from, by kind
    (:func:`~observer_gym.train.core.entries.entry_identity`: import path,
    distribution, version, the sha256 of the factory's module or the object's hash); {}
    for the package's own entries and agents. Sweeps and benchmarks key their cells and
    levels by it, so an upgraded package's entry does not reuse another's."""
    found: dict[str, dict[str, Any]] = {}
    if observer.plugin is not None:
        found["observer"] = entries.entry_identity(observer.plugin)
    if controller.plugin is not None:
        found["controller"] = entries.entry_identity(controller.plugin)
    return found


def check_entries(
    system: System,
    observer: ObserverEntry,
    controller: ControllerEntry,
    env_kwargs: Mapping[str, Any] | None = None,
    seed: int = 0,
) -> None:
    """Try an outside observer or controller once before anything runs: refuse one whose
    factory declares other systems (:func:`~observer_gym.train.core.entries.check_declared`),
    then build the env, the pipeline and the controller (with the entries' options),
    reset with ``seed``, and ask for one action (the estimate's layout and the action are
    checked as in every step). ValueError, one line naming the entry, the system and what
    is wrong; nothing for a pair of the package's own (tested) entries."""
    if not is_outside(observer, controller):
        return
    for plugin in (observer.plugin, controller.plugin):
        if plugin is not None:
            entries.check_declared(plugin, system.env_id, system.short_id)
    env = make_env(system, observer, env_kwargs)
    try:
        built = build_controller(controller, env, system)
        env = getattr(built, "wrap_env", lambda env: env)(env)
        getattr(built, "reset", lambda: None)()
        obs, info = env.reset(seed=seed)
        getattr(built, "observe_info", lambda info: None)(info)
        action, _ = built.predict(obs)
        env.step(action)
    except ValueError as exc:
        raise ValueError(f"{exc} (on {system.short_id}, tried before any episode)") from exc
    except Exception as exc:  # an outside observer's own fault, raised inside the wrappers
        raise ValueError(
            f"observer {observer.name!r} with controller {controller.name!r} fails on "
            f"{system.short_id} (tried before any episode): {type(exc).__name__}: {exc}"
        ) from exc
    finally:
        env.close()


def build_controller(controller: ControllerEntry, env: gym.Env, system: System) -> Any:
    """The controller of ``controller`` (resolved for ``system``, ``env``'s system) with
    its options: a trained agent for ``ALGO:DIR``, a
    :class:`~observer_gym.train.core.controller_entries.PolicyFile` for ``ALGO:PATH.zip``,
    the :class:`~observer_gym.train.core.controller_entries.CheckedController` of an outside
    factory, else the system's design (:func:`~observer_gym.controllers.design_controller`:
    its one look-up of the system's controllers)."""
    name, options = controller.name, controller.options
    agent_spec = parse_agent_spec(name)
    if controller.kind in ("agent", "policy") and agent_spec is not None:
        if options:
            raise ValueError(f"controller {name!r} takes no options, got {dict(options)}")
        if controller.kind == "policy":
            return PolicyFile(agent_spec[0], agent_spec[1], env)
        return Agent.load(agent_spec[1], algo=agent_spec[0])
    if controller.plugin is not None:
        return CheckedController(controller.plugin, env, options)
    return design_controller(name, controllers_of(system)[name], env, options)


def describe_controller(controller: Any) -> dict[str, Any]:
    """The controller's name, class and the design values in :data:`CONTROLLER_ATTRIBUTES`."""
    described: dict[str, Any] = {"name": controller.name, "class": type(controller).__name__}
    # An MPC's Q, R and K are its LQR's; a controller's own attributes come last and win.
    sources = [getattr(controller, "lqr", None), controller]
    for source in filter(None, sources):
        for attr in CONTROLLER_ATTRIBUTES:
            if hasattr(source, attr):
                described[attr] = to_jsonable(getattr(source, attr))
    return described


def run_episode(spec: EpisodeSpec) -> dict[str, Any]:
    """:func:`run_episode_here` with the spec's entries given as objects findable."""
    with entries.objects_in_use(spec.objects):
        return run_episode_here(spec)


def run_episode_here(spec: EpisodeSpec) -> dict[str, Any]:
    """Run one episode; its record (arrays, T steps).

    Returns ``time_s`` (T + 1,), ``state`` (T + 1, n) ground truth, ``estimate`` and
    ``estimate_std`` (T + 1, n; None for the oracle), for an observer also ``nees``,
    ``nees_dof``, ``nis``, ``nis_dof`` (T + 1,; :mod:`observer_gym.train.reports.consistency`;
    NaN where a step has none, and on the steps where the env says its observers' model
    does not hold: ``model_holds_key``), ``actions`` (T, m), ``rewards``
    (T,), ``terminated``, ``truncated``, ``final_info`` (the scalar entries of the last
    step's info, e.g. an episode's outcome), ``solver_failures``, ``controller``
    (:func:`describe_controller`) and ``env_config`` (the env's full configuration).
    Stops at termination, truncation (the env's time limit) or ``spec.max_steps``.
    """
    env = make_env(spec.system, spec.observer, spec.env_kwargs)
    try:
        controller = build_controller(spec.controller, env, spec.system)
        # An agent sees the env through the wrappers it was trained with (image resizing
        # and frame stacking for rgb); info, with the ground truth, passes through them.
        env = getattr(controller, "wrap_env", lambda env: env)(env)
        controller.reset()
        failures_before = getattr(controller, "failures", 0)
        # A controller that uses more than the observation (the intercept planner reads
        # the estimate's covariance) gets every info through observe_info.
        observe_info = getattr(controller, "observe_info", lambda info: None)
        actions: list[np.ndarray] = []
        rewards: list[float] = []
        terminated = truncated = False
        video = None if spec.video is None else EpisodeVideo(spec.video, env)
        recording = None
        try:
            if spec.rerun is not None:
                from observer_gym.train.reports.rerun_recording import EpisodeRerun

                recording = EpisodeRerun(spec.rerun, env)
            obs, info = env.reset(seed=spec.seed, options=spec.reset_options)
            # The ground truth as the env gave it, copied before any entry sees the step
            # (outside entries are shown read-only copies: entry_guard).
            states = [np.array(info["state"], dtype=float)]
            observe_info(info)
            samples = [info]
            if video is not None:
                video.add(info, 0)
            if recording is not None:
                recording.add(info, 0)
            while not (terminated or truncated) and (
                spec.max_steps is None or len(actions) < spec.max_steps
            ):
                action, _ = controller.predict(obs)
                obs, reward, terminated, truncated, info = env.step(action)
                states.append(np.array(info["state"], dtype=float))
                observe_info(info)
                actions.append(np.asarray(action, dtype=float))
                rewards.append(float(reward))
                samples.append(info)
                if video is not None:
                    video.add(info, len(actions), actions[-1])
                if recording is not None:
                    recording.add(info, len(actions), actions[-1])
            if video is not None:
                video.finish()
            if recording is not None:
                recording.finish()
        except ValueError as exc:  # an observer's or controller's fault: which episode, when
            raise EpisodeError(
                f"{exc} (episode seed {spec.seed}, after {len(actions)} steps)"
            ) from None
        finally:
            if video is not None:
                video.abort()  # after finish() a no-op; else the temps go
            if recording is not None:
                recording.abort()  # after finish() the temp is gone already
        record: dict[str, Any] = {
            # Rounded to the nanosecond: the env sums dt, which leaves float dust (0.74000..03).
            "time_s": np.round([s["time_s"] for s in samples], 9),
            "state": np.array(states),
            "estimate": None,
            "estimate_std": None,
            "actions": np.array(actions).reshape(len(actions), *env.action_space.shape),
            "rewards": np.array(rewards),
            "terminated": bool(terminated),
            "truncated": bool(truncated),
            "final_info": {
                k: v for k, v in samples[-1].items() if isinstance(v, (bool, int, float, str))
            },
            "solver_failures": int(getattr(controller, "failures", 0) - failures_before),
            "controller": describe_controller(controller),
            "env_config": dataclasses.asdict(env.unwrapped.config),
        }
        if "estimate" in samples[0]:
            estimates = [s["estimate"] for s in samples]
            record["estimate"] = np.array([e["mean"] for e in estimates], dtype=float)
            covariances = [e["covariance"] for e in estimates]
            variances = np.array([np.diag(P) for P in covariances], dtype=float)
            record["estimate_std"] = np.sqrt(np.maximum(variances, 0.0))
            record["nees"], record["nees_dof"] = nees_per_step(
                record["estimate"], covariances, record["state"]
            )
            record["nis"] = np.array(
                [np.nan if e.get("nis") is None else e["nis"] for e in estimates], dtype=float
            )
            record["nis_dof"] = np.array([e.get("nis_dof", 0) for e in estimates], dtype=int)
            _keep_where_model_holds(record, env.unwrapped, samples)
        return record
    finally:
        env.close()


def _keep_where_model_holds(record: dict[str, Any], env: gym.Env, samples: list) -> None:
    """NEES and NIS only over the steps where the observers' process model holds (the
    env's ``model_holds_key`` info entry, e.g. BallCatcher's ball in free flight): NaN and
    0 dof elsewhere."""
    key = getattr(env, "model_holds_key", None)
    if key is None:
        return
    outside = ~np.array([bool(s.get(key, True)) for s in samples])
    for name in ("nees", "nis"):
        record[name][outside] = np.nan
        record[f"{name}_dof"][outside] = 0


def iter_episodes(
    specs: Sequence[EpisodeSpec],
    workers: int = 1,
    run: Callable[[EpisodeSpec], Any] = run_episode,
) -> Generator[tuple[int, Any], None, None]:
    """``(index, run(specs[index]))`` for every spec, as each finishes: in order in this
    process for ``workers`` == 1, else in ``workers`` spawned processes (``run`` must then
    be a module-level function), in the order they finish. The first episode that fails
    raises at once (with a note naming it), and the episodes not started are dropped; so
    are they when the caller stops iterating (Ctrl-C, or an error of its own)."""
    if workers == 1:
        for index, spec in enumerate(specs):
            yield index, run(spec)
        return
    context = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(
        max_workers=min(workers, len(specs)), mp_context=context, initializer=end_with_parent
    ) as pool:
        futures = {pool.submit(run, spec): index for index, spec in enumerate(specs)}
        try:
            for future in concurrent.futures.as_completed(futures):
                error = future.exception()
                if error is not None:  # ends the run now, not after the other episodes
                    if sys.version_info >= (3, 11):  # add_note is 3.11's; 3.10 raises as is
                        error.add_note(f"in the episode {specs[futures[future]]}")
                    raise error
                yield futures[future], future.result()
        except BaseException:  # a failed episode, Ctrl-C, or the caller stopped iterating
            for pending in futures:
                pending.cancel()  # the episodes not started yet are dropped
            raise


def run_episodes(
    specs: Sequence[EpisodeSpec], workers: int = 1, progress: bool = True, desc: str = "run"
) -> list[dict]:
    """The records of ``specs`` (:func:`run_episode`), in order; in ``workers`` spawned
    processes if > 1, with the same results (:func:`iter_episodes`: the first episode
    that fails raises at once, naming it)."""
    records: list[Any] = [None] * len(specs)
    if not specs:
        return []
    with progress_bar(total=len(specs), unit="episode", desc=desc, disable=not progress) as bar:
        for index, record in iter_episodes(specs, workers):
            records[index] = record
            bar.update(1)
    return records
