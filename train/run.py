"""``observer-gym run``: closed-loop episodes of a controller on the oracle state or on an
observer's estimate, with metrics, a summary, plots and ``results.json``.

Each episode is self-contained: it builds its own env and controller, resets with
``seed + episode`` and closes the env, so any episode can be rerun alone and running the
episodes in several processes gives exactly the results of one.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import multiprocessing
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from tqdm import tqdm

import observer_gym.envs
from observer_gym.controllers import CONTROLLERS, make_controller
from observer_gym.envs.ball_table.layout import BALL_POS
from observer_gym.estimation import VisionObserver
from observer_gym.train.metrics import TOLERANCE_M, distance_from_centre_m, episode_metrics
from observer_gym.train.metrics import summarize as summarize_episodes
from observer_gym.train.outputs import (
    format_table,
    package_versions,
    to_jsonable,
    write_json_atomic,
)
from observer_gym.train.plots import plot_distances, plot_estimate, plot_paths

# observer name -> the env's obs_mode; every mode but "state" is wrapped in VisionObserver.
OBSERVERS: dict[str, str] = {"oracle": "state", "kf": "rgb", "kf-measurements": "measurements"}
PATH_PLOT_EPISODES = 5  # path.png shows the first this many episodes
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
)


def resolve_env_id(name: str) -> str:
    """The registered id for ``name``: a registered id or its name without the
    ``observer_gym/`` namespace. Anything else raises ``ValueError`` listing them."""
    for env_id in observer_gym.envs.ENV_IDS:
        if name in (env_id, env_id.split("/", 1)[-1]):
            return env_id
    allowed = ", ".join(
        f"{env_id.split('/', 1)[-1]} (or {env_id})" for env_id in observer_gym.envs.ENV_IDS
    )
    raise ValueError(f"unknown env {name!r}; allowed: {allowed}")


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


def make_env(env_id: str, observer: str, env_kwargs: Mapping[str, Any] | None = None) -> gym.Env:
    """The env for ``observer``: the state env for "oracle", else the env in the observer's
    obs_mode wrapped in :class:`VisionObserver`. ``env_kwargs`` go to ``gym.make``."""
    env = gym.make(env_id, obs_mode=OBSERVERS[observer], **dict(env_kwargs or {}))
    if observer == "oracle":
        return env
    try:
        return VisionObserver(env)
    except BaseException:
        env.close()
        raise


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
    """Run one episode; its record (arrays, T steps).

    Returns ``time_s`` (T + 1,), ``state`` (T + 1, 8) ground truth, ``estimate`` and
    ``estimate_std`` (T + 1, 8; None for the oracle), ``actions_rad`` (T, 2),
    ``rewards`` (T,), ``terminated``, ``truncated``, ``solver_failures``, ``controller``
    (:func:`describe_controller`) and ``env_config`` (the env's full configuration).
    Stops at termination, truncation (the env's time limit) or ``spec.max_steps``.
    """
    env = make_env(spec.env_id, spec.observer, spec.env_kwargs)
    try:
        controller = make_controller(spec.controller, env)
        controller.reset()
        failures_before = getattr(controller, "failures", 0)
        obs, info = env.reset(seed=spec.seed, options=spec.reset_options)
        samples = [info]
        actions, rewards = [], []
        terminated = truncated = False
        while not (terminated or truncated) and (
            spec.max_steps is None or len(actions) < spec.max_steps
        ):
            action, _ = controller.predict(obs)
            obs, reward, terminated, truncated, info = env.step(action)
            actions.append(np.asarray(action, dtype=float))
            rewards.append(float(reward))
            samples.append(info)
        record: dict[str, Any] = {
            # Rounded to the nanosecond: the env sums dt, which leaves float dust (0.74000..03).
            "time_s": np.round([s["time_s"] for s in samples], 9),
            "state": np.array([s["state"] for s in samples], dtype=float),
            "estimate": None,
            "estimate_std": None,
            "actions_rad": np.array(actions).reshape(-1, 2),
            "rewards": np.array(rewards),
            "terminated": bool(terminated),
            "truncated": bool(truncated),
            "solver_failures": int(getattr(controller, "failures", 0) - failures_before),
            "controller": describe_controller(controller),
            "env_config": dataclasses.asdict(env.unwrapped.config),
        }
        if spec.observer != "oracle":
            estimates = [s["estimate"] for s in samples]
            record["estimate"] = np.array([e["mean"] for e in estimates], dtype=float)
            variances = np.array([np.diag(e["covariance"]) for e in estimates], dtype=float)
            record["estimate_std"] = np.sqrt(np.maximum(variances, 0.0))
        return record
    finally:
        env.close()


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
) -> dict[str, Any]:
    """Run ``episodes`` closed-loop episodes; write results and plots; print a table.

    Episode i resets with ``seed + i`` (and ``reset_options``, e.g. a fixed start) and
    runs to the env's time limit (500 steps, 10 s), the ball leaving the table, or
    ``steps`` steps. With ``workers`` > 1 the episodes run in that many spawned processes,
    with results identical to ``workers=1``.

    Writes into ``out_dir`` (created): ``path.png`` (ball paths of the first episodes),
    ``error.png`` (distance from the centre vs time), ``estimate.png`` for the observers
    (episode 0's estimate vs truth with ±2σ) and, last, ``results.json`` (atomically):
    ``config``, ``seed``, ``versions``, ``episodes`` (per-episode metrics, see
    :func:`observer_gym.train.metrics.episode_metrics`), ``summary``, ``files``.

    Args:
        env_id: "BallTable-v0" or "observer_gym/BallTable-v0".
        observer: one of :data:`OBSERVERS`.
        controller: one of ``observer_gym.controllers.CONTROLLERS``.
        episodes: number of episodes (>= 1).
        seed: seed of episode 0.
        out_dir: the output folder.
        steps: cap on each episode's steps (None: the env's time limit).
        workers: processes to run episodes in (>= 1).
        progress: show a tqdm bar over episodes.
        env_kwargs: extra ``gym.make`` options (the observer sets ``obs_mode``).
        reset_options: options for every ``env.reset``.
        cli_args: the command line's arguments, recorded in the config.

    Returns:
        What ``results.json`` holds (JSON types).

    Raises:
        ValueError: an unknown env, observer or controller, a count < 1 or a negative seed.
    """
    env_id = resolve_env_id(env_id)
    if observer not in OBSERVERS:
        raise ValueError(f"unknown observer {observer!r}; allowed: {', '.join(OBSERVERS)}")
    if controller not in CONTROLLERS:
        raise ValueError(f"unknown controller {controller!r}; allowed: {', '.join(CONTROLLERS)}")
    for name, value in (("episodes", episodes), ("workers", workers), ("steps", steps)):
        if value is not None and (int(value) != value or value < 1):
            raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    if int(seed) != seed or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    env_kwargs = dict(env_kwargs or {})
    if "obs_mode" in env_kwargs:
        raise ValueError("env_kwargs must not set obs_mode: the observer decides it")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)

    specs = [
        EpisodeSpec(env_id, observer, controller, seed + i, steps, env_kwargs, reset_options)
        for i in range(episodes)
    ]
    tic_s = time.perf_counter()
    records = _run_all(specs, workers, progress)
    wall_time_s = time.perf_counter() - tic_s

    per_episode = []
    for i, (spec, record) in enumerate(zip(specs, records, strict=True)):
        metrics = episode_metrics(
            record["time_s"],
            record["state"],
            record["actions_rad"],
            record["rewards"],
            estimate=record["estimate"],
            terminated=record["terminated"],
            solver_failures=record["solver_failures"],
        )
        per_episode.append({"episode": i, "seed": spec.seed, **metrics})
    summary = summarize_episodes(per_episode)

    files = _plot(records, observer, out_dir)
    files.append("results.json")
    results = to_jsonable(
        {
            "config": {
                "env_id": env_id,
                "env_kwargs": {"obs_mode": OBSERVERS[observer], **env_kwargs},
                "env_config": records[0]["env_config"],
                "observer": observer,
                "controller": controller,
                "controller_config": records[0]["controller"],
                "episodes": episodes,
                "seed": seed,
                "steps": steps,
                "workers": workers,
                "reset_options": reset_options,
                "tolerance_m": TOLERANCE_M,
                "out_dir": str(out_dir),
                "cli_args": cli_args,
            },
            "seed": seed,
            "versions": package_versions(),
            "wall_time_s": wall_time_s,
            "episodes": per_episode,
            "summary": summary,
            "files": files,
        }
    )
    write_json_atomic(out_dir / "results.json", results)
    print(
        f"observer-gym run: {env_id}, observer {observer}, controller {controller}, "
        f"{episodes} episode(s), seeds {seed}..{seed + episodes - 1}, {wall_time_s:.1f} s"
    )
    print(summary_table(summary))
    print(f"output: {out_dir}")
    return results


def _run_all(specs: Sequence[EpisodeSpec], workers: int, progress: bool) -> list[dict]:
    """The records of ``specs``, in order; in ``workers`` spawned processes if > 1."""
    bar = tqdm(total=len(specs), unit="episode", desc="run", disable=not progress)
    with bar:
        if workers == 1:
            records = []
            for spec in specs:
                records.append(run_episode(spec))
                bar.update(1)
            return records
        context = multiprocessing.get_context("spawn")
        with concurrent.futures.ProcessPoolExecutor(
            max_workers=min(workers, len(specs)), mp_context=context
        ) as pool:
            futures = [pool.submit(run_episode, spec) for spec in specs]
            for _ in concurrent.futures.as_completed(futures):
                bar.update(1)
            return [future.result() for future in futures]


def _plot(records: Sequence[dict], observer: str, out_dir: Path) -> list[str]:
    """Write the plots of ``records``; their file names."""
    shown = records[:PATH_PLOT_EPISODES]
    plot_paths(
        [r["state"][:, BALL_POS] for r in shown],
        out_dir / "path.png",
        title=f"Ball path, table frame (first {len(shown)} of {len(records)} episodes)",
    )
    plot_distances(
        [r["time_s"] for r in records],
        [distance_from_centre_m(r["state"][:, BALL_POS]) for r in records],
        out_dir / "error.png",
    )
    files = ["path.png", "error.png"]
    if observer != "oracle":
        first = records[0]
        plot_estimate(
            first["time_s"],
            first["state"][:, BALL_POS],
            first["estimate"][:, BALL_POS],
            first["estimate_std"][:, BALL_POS],
            out_dir / "estimate.png",
            title=f"Observer '{observer}' estimate of the ball position, episode 0",
        )
        files.append("estimate.png")
    return files


# summary key -> (label, unit, scale from the stored SI value to the shown unit, digits)
SUMMARY_ROWS: dict[str, tuple[str, str, float, int]] = {
    "episodes": ("episodes", "", 1.0, 0),
    "fraction_settled": ("fraction settled (1 cm)", "", 1.0, 2),
    "settling_time_mean_s": ("settling time, mean (settled)", "s", 1.0, 2),
    "settling_time_median_s": ("settling time, median (settled)", "s", 1.0, 2),
    "settling_time_max_s": ("settling time, max (settled)", "s", 1.0, 2),
    "mean_distance_m": ("distance from centre, mean", "mm", 1e3, 2),
    "final_distance_m": ("final distance from centre, mean", "mm", 1e3, 2),
    "time_within_s": ("time within 1 cm, mean", "s", 1.0, 2),
    "effort_rms_rad": ("control effort (RMS tilt command), mean", "mrad", 1e3, 2),
    "position_rmse_m": ("estimation RMSE position, mean", "mm", 1e3, 3),
    "velocity_rmse_mps": ("estimation RMSE velocity, mean", "mm/s", 1e3, 2),
    "return": ("return, mean", "", 1.0, 1),
    "solver_failures": ("solver failures (total)", "", 1.0, 0),
    "terminated": ("terminated (ball off the table)", "", 1.0, 0),
}


def summary_table(summary: Mapping[str, Any]) -> str:
    """A Markdown table with one row per summary metric, in readable units."""
    rows = []
    for key, (label, unit, scale, digits) in SUMMARY_ROWS.items():
        value = summary[key]
        text = "-" if value is None else f"{value * scale:.{digits}f}"
        rows.append([label, text, unit])
    return format_table(["metric", "value", "unit"], rows)
