"""``observer-gym run``: closed-loop episodes of a controller on the oracle state or on an
observer's estimate, with metrics, a summary, plots and ``results.json``.

What is measured and drawn depends on the env: its task module in
:mod:`observer_gym.train.tasks` supplies the observers, metrics, summary rows and plots.

Each episode is self-contained: it builds its own env and controller, resets with
``seed + episode`` and closes the env, so any episode can be rerun alone and running the
episodes in several processes gives exactly the results of one.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import multiprocessing
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from tqdm import tqdm

from observer_gym.controllers import (
    controllers_for,
    controllers_of,
    make_controller,
)
from observer_gym.envs import system_of
from observer_gym.train import entries
from observer_gym.train.agent import Agent
from observer_gym.train.consistency import (
    NEES_COLUMN,
    consistency_text,
    episode_consistency,
    nees_flag,
    nees_per_step,
)
from observer_gym.train.controller_entries import (
    CheckedController,
    PolicyFile,
    is_policy_file,
)
from observer_gym.train.observer_env import make_env, observer_setup
from observer_gym.train.outputs import (
    format_table,
    json_text,
    output_folder,
    output_set,
    package_versions,
    to_jsonable,
    write_json_atomic,
)
from observer_gym.train.request import Request, check_pair, resolve_request
from observer_gym.train.run_dir import parse_agent_spec
from observer_gym.train.tasks import task_for

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
    """Everything one episode needs; picklable, so a worker process can run it."""

    env_id: str
    observer: str
    controller: str
    seed: int
    max_steps: int | None = None
    env_kwargs: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    reset_options: Mapping[str, Any] | None = None
    observer_options: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    controller_options: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    # the observer and controller if given as Python objects (entries.as_name), by name:
    # they travel with the spec to a worker
    objects: Mapping[tuple[str, str], Any] = dataclasses.field(default_factory=dict)

    @classmethod
    def of(
        cls, env_id: str, observer: str, controller: str, seed: int, **fields: Any
    ) -> EpisodeSpec:
        """The spec with the objects the observer and controller names stand for, if any."""
        return cls(
            env_id, observer, controller, seed, **fields,
            objects=entries.objects_for(observer, controller),
        )  # fmt: skip


class EpisodeError(ValueError):
    """An episode that failed part-way (an observer's or a controller's fault): the
    message names it, the episode's seed and the step."""


def is_outside(env_id: str, observer: str, controller: str) -> bool:
    """Whether the pair has an outside observer or controller (an import path, an entry
    point, or a stable-baselines3 zip): what :func:`check_entries` tries."""
    agent_spec = parse_agent_spec(controller)
    outside_controller = (
        is_policy_file(agent_spec[1])
        if agent_spec is not None
        else controller not in controllers_for(env_id)
    )
    return observer_setup(env_id, observer)[2] is not None or outside_controller


def check_entries(
    env_id: str,
    observer: str,
    controller: str,
    env_kwargs: Mapping[str, Any] | None = None,
    observer_options: Mapping[str, Any] | None = None,
    controller_options: Mapping[str, Any] | None = None,
    seed: int = 0,
) -> None:
    """Try an outside observer or controller once before anything runs: build the env,
    the pipeline and the controller, reset with ``seed``, and ask for one action (the
    estimate's layout and the action are checked as in every step). ValueError naming the
    entry and what is wrong; nothing for a pair of the package's own (tested) entries."""
    if not is_outside(env_id, observer, controller):
        return
    env = make_env(env_id, observer, env_kwargs, observer_options)
    try:
        built = build_controller(controller, env, controller_options)
        env = getattr(built, "wrap_env", lambda env: env)(env)
        getattr(built, "reset", lambda: None)()
        obs, info = env.reset(seed=seed)
        getattr(built, "observe_info", lambda info: None)(info)
        action, _ = built.predict(obs)
        env.step(action)
    finally:
        env.close()


def build_controller(
    controller: str, env: gym.Env, options: Mapping[str, Any] | None = None
) -> Any:
    """The controller named ``controller`` for ``env``: a trained agent for ``ALGO:DIR``,
    a :class:`~observer_gym.train.controller_entries.PolicyFile` for ``ALGO:PATH.zip``,
    the :class:`~observer_gym.train.controller_entries.CheckedController` of an outside
    factory called with ``options``, else ``make_controller(controller, env, **options)``."""
    agent_spec = parse_agent_spec(controller)
    if agent_spec is not None:
        if options:
            raise ValueError(f"controller {controller!r} takes no options, got {dict(options)}")
        if is_policy_file(agent_spec[1]):
            return PolicyFile(agent_spec[0], agent_spec[1], env)
        return Agent.load(agent_spec[1], algo=agent_spec[0])
    if controller not in controllers_of(system_of(env)):
        plugin = entries.find_plugin("controller", controller)
        if plugin is not None:
            return CheckedController(plugin, env, options or {})
    return make_controller(controller, env, **dict(options or {}))


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
    ``nees_dof``, ``nis``, ``nis_dof`` (T + 1,; :mod:`observer_gym.train.consistency`;
    NaN where a step has none, and on the steps where the env says its observers' model
    does not hold: ``model_holds_key``), ``actions`` (T, m), ``rewards``
    (T,), ``terminated``, ``truncated``, ``final_info`` (the scalar entries of the last
    step's info, e.g. an episode's outcome), ``solver_failures``, ``controller``
    (:func:`describe_controller`) and ``env_config`` (the env's full configuration).
    Stops at termination, truncation (the env's time limit) or ``spec.max_steps``.
    """
    env = make_env(spec.env_id, spec.observer, spec.env_kwargs, spec.observer_options)
    try:
        controller = build_controller(spec.controller, env, spec.controller_options)
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
        try:
            obs, info = env.reset(seed=spec.seed, options=spec.reset_options)
            observe_info(info)
            samples = [info]
            while not (terminated or truncated) and (
                spec.max_steps is None or len(actions) < spec.max_steps
            ):
                action, _ = controller.predict(obs)
                obs, reward, terminated, truncated, info = env.step(action)
                observe_info(info)
                actions.append(np.asarray(action, dtype=float))
                rewards.append(float(reward))
                samples.append(info)
        except ValueError as exc:  # an observer's or controller's fault: which episode, when
            raise EpisodeError(
                f"{exc} (episode seed {spec.seed}, after {len(actions)} steps)"
            ) from None
        record: dict[str, Any] = {
            # Rounded to the nanosecond: the env sums dt, which leaves float dust (0.74000..03).
            "time_s": np.round([s["time_s"] for s in samples], 9),
            "state": np.array([s["state"] for s in samples], dtype=float),
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


def run_experiment(
    env_id: str,
    observer: str,
    controller: str,
    episodes: int,
    seed: int,
    out_dir: str | Path,
    steps: int | None = None,
    workers: int = 1,
    progress: bool = True,
    env_kwargs: Mapping[str, Any] | None = None,
    reset_options: Mapping[str, Any] | None = None,
    cli_args: Mapping[str, Any] | None = None,
    observer_options: Mapping[str, Any] | None = None,
    controller_options: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Run ``episodes`` closed-loop episodes; write results and plots.

    Episode i resets with ``seed + i`` (and ``reset_options``, e.g. a fixed start) and
    runs to the env's end (termination or its time limit) or ``steps`` steps. With
    ``workers`` > 1 the episodes run in that many spawned processes, with results
    identical to ``workers=1``.

    Writes into ``out_dir`` (created; see :func:`~observer_gym.train.outputs.output_folder`
    for what is removed and reported there before, and the folder removed again if the
    run fails before writing anything) the task's plots (BallTable: ``path.png``,
    ``error.png``, ``estimate.png`` for the observers) and, last, ``results.json``:
    ``config``, ``seed``, ``versions``, ``episodes`` (per-episode metrics of the task's
    ``episode_metrics``), ``summary``, ``files``; as a set
    (:func:`~observer_gym.train.outputs.output_set`): all of them or, if one fails, none.

    Args:
        env_id: a registered id, with or without ``observer_gym/`` ("BallTable-v0").
        observer: one of the task's ``OBSERVERS`` (BallTable: oracle, kf, kf-latency, ekf,
            raw, oracle-visible, each but oracle also as NAME-measurements, and pixels), or
            an outside observer (:mod:`observer_gym.train.entries`).
        controller: one of the env's ``observer_gym.controllers.controllers_for(env_id)``,
            a trained agent ``ALGO:DIR`` (``ppo:runs/ppo-balltable``), a stable-baselines3
            zip ``ALGO:PATH.zip`` or an outside controller.
        episodes: number of episodes (>= 1).
        seed: seed of episode 0.
        out_dir: the output folder.
        steps: cap on each episode's steps (None: the env's time limit).
        workers: processes to run episodes in (>= 1).
        progress: show a tqdm bar over episodes.
        env_kwargs: extra ``gym.make`` options (the observer sets ``obs_mode``).
        reset_options: options for every ``env.reset``.
        cli_args: the command line's arguments, recorded in the config.
        observer_options, controller_options: keyword arguments of the observer's pipeline
            and of the controller's factory (or design), recorded in the config.

    Returns:
        What ``results.json`` holds (JSON types).

    Raises:
        ValueError: an unknown env, observer or controller, a count < 1 or a negative seed.
    """
    env_id = check_pair(env_id, observer, controller)  # the messages of the command's checks
    for name, value in (("episodes", episodes), ("workers", workers), ("steps", steps)):
        if value is not None and (int(value) != value or value < 1):
            raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    if int(seed) != seed or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    env_kwargs = dict(env_kwargs or {})
    if "obs_mode" in env_kwargs:
        raise ValueError("env_kwargs must not set obs_mode: the observer decides it")
    request = resolve_request(
        env_id, [observer], [controller], range(seed, seed + episodes), workers, "local", None,
        steps, env_kwargs, observer_options, controller_options,
    )  # fmt: skip
    observer_entry, controller_entry = request.observers[0], request.controllers[0]
    check_entries(
        env_id, observer, controller, env_kwargs, observer_entry.options,
        controller_entry.options, seed,
    )  # fmt: skip
    out_dir = Path(out_dir)
    with output_folder(out_dir, "run"):
        return _run_into(
            out_dir, request, reset_options, cli_args, progress,
        )  # fmt: skip


def _run_into(
    out_dir: Path,
    request: Request,
    reset_options: Mapping[str, Any] | None,
    cli_args: Mapping[str, Any] | None,
    progress: bool,
) -> dict[str, Any]:
    """:func:`run_experiment`'s episodes and outputs, its request checked."""
    observer, controller = request.observers[0], request.controllers[0]
    task, env_kwargs, seeds = request.task, request.env_kwargs, request.seeds
    specs = [
        EpisodeSpec.of(
            request.env_id,
            observer.name,
            controller.name,
            seed,
            max_steps=request.steps,
            env_kwargs=env_kwargs,
            reset_options=reset_options,
            observer_options=observer.options,
            controller_options=controller.options,
        )
        for seed in seeds
    ]
    tic_s = time.perf_counter()
    records = run_episodes(specs, request.workers, progress)
    wall_time_s = time.perf_counter() - tic_s

    per_episode = [
        {
            "episode": i,
            "seed": spec.seed,
            **task.episode_metrics(record),
            **episode_consistency(record),
        }
        for i, (spec, record) in enumerate(zip(specs, records, strict=True))
    ]
    summary = task.summarize(per_episode)
    consistency = nees_flag(per_episode)._asdict()
    observed = observer.record()

    results = to_jsonable(
        {
            "config": {
                "env_id": request.env_id,
                "env_kwargs": {"obs_mode": observed["obs_mode"], **env_kwargs},
                **{k: v for k, v in observed.items() if k != "obs_mode"},
                "controller_options": controller.options,
                "env_config": records[0]["env_config"],
                "observer": observer.name,
                "controller": controller.name,
                "controller_config": records[0]["controller"],
                "episodes": len(seeds),
                "seed": seeds[0],
                "steps": request.steps,
                "workers": request.workers,
                "reset_options": reset_options,
                **task.CONFIG,
                "out_dir": str(out_dir),
                "cli_args": cli_args,
            },
            "seed": seeds[0],
            "versions": package_versions(),
            "wall_time_s": wall_time_s,
            "episodes": per_episode,
            "summary": summary,
            "consistency": consistency,
        }
    )
    try:
        json_text(results)
    except ValueError as exc:
        raise ValueError(f"results.json cannot be written: {exc}") from None
    with output_set(out_dir) as staging:  # the plots and results.json, all or none
        results["files"] = [*task.plot(records, observer.name, staging), "results.json"]
        write_json_atomic(staging / "results.json", results)
    return results


def results_text(results: Mapping[str, Any]) -> str:
    """What ``observer-gym run`` and ``evaluate`` print of :func:`run_experiment`'s
    results: what ran, the task's summary table and the output folder."""
    config = results["config"]
    first, episodes = config["seed"], config["episodes"]
    last = first + episodes - 1
    lines = [
        f"observer-gym run: {config['env_id']}, observer {config['observer']}, controller "
        f"{config['controller']}, {episodes} episode(s), seeds {first}..{last}, "
        f"{results['wall_time_s']:.1f} s",
        *entry_lines(config.get("entry"), config["controller_config"].get("entry")),
        summary_table(results["summary"], task_for(config["env_id"]).SUMMARY_ROWS),
    ]
    consistency = results.get("consistency")
    if consistency and consistency.get("nees_ratio") is not None:
        lines.append(f"{NEES_COLUMN}: {consistency_text(consistency)}")
    return "\n".join([*lines, f"output: {config['out_dir']}"])


def entry_lines(observer: Mapping | None, controller: Mapping | None) -> list[str]:
    """The header lines naming an outside observer's and controller's entries."""
    pairs = (("observer", observer), ("controller", controller))
    return [entries.entry_line(kind, entry) for kind, entry in pairs if entry]


def iter_episodes(
    specs: Sequence[EpisodeSpec],
    workers: int = 1,
    run: Callable[[EpisodeSpec], Any] = run_episode,
) -> Iterator[tuple[int, Any]]:
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
        max_workers=min(workers, len(specs)), mp_context=context
    ) as pool:
        futures = {pool.submit(run, spec): index for index, spec in enumerate(specs)}
        try:
            for future in concurrent.futures.as_completed(futures):
                error = future.exception()
                if error is not None:  # ends the run now, not after the other episodes
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
    with tqdm(total=len(specs), unit="episode", desc=desc, disable=not progress) as bar:
        for index, record in iter_episodes(specs, workers):
            records[index] = record
            bar.update(1)
    return records


def summary_table(
    summary: Mapping[str, Any], rows: Mapping[str, tuple[str, str, float, int]]
) -> str:
    """A Markdown table with one row per entry of ``rows`` (a task's ``SUMMARY_ROWS``:
    key -> label, unit, scale from the stored SI value, digits), in readable units."""
    lines = []
    for key, (label, unit, scale, digits) in rows.items():
        value = summary[key]
        text = "-" if value is None else f"{value * scale:.{digits}f}"
        lines.append([label, text, unit])
    return format_table(["metric", "value", "unit"], lines)
