"""``observer-gym compare``: every (observer, controller) pair of one env on the same seeds.

Episode i of every pair resets with the same seed, so every pair starts from the same
state and, as far as the env draws its disturbances from the reset seed, meets the same
disturbances: differences between pairs are paired, episode by episode. Each pair's
per-episode metrics come from the env's task module (:mod:`observer_gym.train.tasks`),
whose ``COMPARE_METRICS`` decides which go into the table (the first is the primary
metric, the one of the "oracle vs observer" column).

All episodes run in one batch, locally (:func:`observer_gym.train.run.run_episodes`, in
worker processes) or as Ray tasks (:mod:`observer_gym.train.ray_backend`); both give the
same results. Writes ``table.md``, ``table.csv``, ``bar_<metric>.png``, the task's plots
of every pair under ``pairs/<observer>__<controller>/`` and, last, ``results.json``.
"""

from __future__ import annotations

import ast
import csv
import importlib.util
import math
import re
import shlex
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from observer_gym.train.agent import parse_agent_spec
from observer_gym.train.outputs import (
    VERSIONED_PACKAGES,
    format_table,
    package_versions,
    to_jsonable,
    write_json_atomic,
)
from observer_gym.train.plots import DPI, new_figure
from observer_gym.train.run import (
    EpisodeSpec,
    build_controller,
    check_controller,
    make_env,
    resolve_env_id,
    run_episodes,
)
from observer_gym.train.tasks import task_for

CONFIDENCE = 0.95  # of every interval
PERCENT = f"{CONFIDENCE * 100:g} %"  # as the tables write it
BACKENDS = ("local", "ray")
ORACLE = "oracle"
BETTER = ("lower", "higher")
RAY_INSTALL_HINT = "pip install 'observer-gym[distributed]'"


# --- statistics ------------------------------------------------------------------------
def _interval_of_nothing(n: int, method: str) -> dict[str, Any]:
    """An interval's fields with every value None, for :func:`mean_interval` and
    :func:`rate_interval` to fill."""
    return {"n": n, "mean": None, "half_width": None, "low": None, "high": None, "method": method}


def mean_interval(values: Sequence[float | None], confidence: float = CONFIDENCE) -> dict[str, Any]:
    """Mean of the values that are not None with its Student t interval.

    Returns ``n`` (values used), ``mean``, ``half_width`` = t_{(1+c)/2, n-1} s / sqrt(n)
    (s: sample standard deviation), ``low``, ``high`` and ``method`` ("student-t"), in the
    values' unit. With n = 1 the interval is undefined (None); with n = 0 so is the mean.
    """
    x = np.array([float(v) for v in values if v is not None], dtype=float)
    n = len(x)
    result = _interval_of_nothing(n, "student-t")
    if n == 0:
        return result
    mean = float(np.mean(x))
    result["mean"] = mean
    if n >= 2:
        sem = float(np.std(x, ddof=1)) / math.sqrt(n)
        half_width = float(stats.t.ppf(0.5 + confidence / 2.0, n - 1)) * sem
        result.update(half_width=half_width, low=mean - half_width, high=mean + half_width)
    return result


def rate_interval(values: Sequence[bool | None], confidence: float = CONFIDENCE) -> dict[str, Any]:
    """Fraction of True among the values that are not None with its Wilson score interval
    (SciPy's ``binomtest(...).proportion_ci(method="wilson")``, as the BallCatcher summary).

    Returns ``n``, ``mean`` (the rate, 0-1), ``half_width`` (None: the interval is not
    symmetric), ``low``, ``high`` and ``method`` ("wilson"); all None but n for n = 0.
    """
    x = [bool(v) for v in values if v is not None]
    n = len(x)
    result = _interval_of_nothing(n, "wilson")
    if n == 0:
        return result
    successes = sum(x)
    interval = stats.binomtest(successes, n).proportion_ci(
        confidence_level=confidence, method="wilson"
    )
    result.update(mean=successes / n, low=float(interval.low), high=float(interval.high))
    return result


def is_flag(values: Sequence[Any]) -> bool:
    """True if every value that is not None is a boolean (an outcome such as "caught")."""
    present = [v for v in values if v is not None]
    return bool(present) and all(isinstance(v, bool | np.bool_) for v in present)


def metric_statistics(values: Sequence[Any], confidence: float = CONFIDENCE) -> dict[str, Any]:
    """:func:`rate_interval` for booleans, else :func:`mean_interval` (None values skipped)."""
    if is_flag(values):
        return rate_interval(values, confidence)
    return mean_interval(values, confidence)


def paired_difference(
    observer_values: Sequence[Any],
    oracle_values: Sequence[Any],
    confidence: float = CONFIDENCE,
) -> dict[str, Any]:
    """Observer minus oracle, episode by episode (same seeds), over the episodes where both
    have a value: :func:`mean_interval` of the differences (booleans count 0/1, so a rate's
    difference is a fraction: x 100 for percentage points), plus ``observer_mean``,
    ``oracle_mean`` (over those episodes) and ``ratio`` = observer_mean / oracle_mean
    (None when the oracle's mean is 0)."""
    if len(observer_values) != len(oracle_values):
        raise ValueError(
            f"paired values differ in length: {len(observer_values)} and {len(oracle_values)}"
        )
    pairs = [
        (float(o), float(r))
        for o, r in zip(observer_values, oracle_values, strict=True)
        if o is not None and r is not None
    ]
    result = mean_interval([o - r for o, r in pairs], confidence)
    result["method"] = "paired student-t"
    observer_mean = float(np.mean([o for o, _ in pairs])) if pairs else None
    oracle_mean = float(np.mean([r for _, r in pairs])) if pairs else None
    result["observer_mean"] = observer_mean
    result["oracle_mean"] = oracle_mean
    ratio = None
    if observer_mean is not None and oracle_mean:  # undefined for an oracle mean of 0
        ratio = observer_mean / oracle_mean
    result["ratio"] = ratio
    return result


# --- validation ------------------------------------------------------------------------
def _names(kind: str, names: Sequence[str] | str, allowed: str) -> list[str]:
    """``names`` as a list (a string is split at commas); ValueError if it is empty, has
    an empty name or names one twice."""
    if isinstance(names, str):
        names = names.split(",")
    names = [str(name).strip() for name in names]
    if not names:
        raise ValueError(f"{kind} must name at least one; allowed: {allowed}")
    if "" in names:
        raise ValueError(f"{kind} has an empty name in {names}; allowed: {allowed}")
    duplicates = sorted({name for name in names if names.count(name) > 1})
    if duplicates:
        raise ValueError(f"{kind} lists {', '.join(map(repr, duplicates))} more than once")
    return names


def _seeds(seeds: Sequence[int]) -> list[int]:
    seeds = list(seeds)
    if not seeds:
        raise ValueError("seeds must hold at least one seed")
    for seed in seeds:
        if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
            raise ValueError(f"seeds must be integers >= 0, got {seed!r}")
    duplicates = sorted({int(s) for s in seeds if seeds.count(s) > 1})
    if duplicates:
        raise ValueError(f"seeds must be distinct; {duplicates} appear more than once")
    return [int(s) for s in seeds]


def check_comparison(
    env_id: str,
    observers: Sequence[str] | str,
    controllers: Sequence[str] | str,
    seeds: Sequence[int],
    workers: int = 1,
    backend: str = "local",
    address: str | None = None,
    steps: int | None = None,
    env_kwargs: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Check a comparison's inputs; return them normalised (``env_id`` registered,
    ``observers``, ``controllers`` and ``seeds`` as lists, ``env_kwargs`` a dict).

    The cheap checks come first and build no env: the env, the observers (the task's
    ``OBSERVERS``), the controllers (:func:`observer_gym.train.run.check_controller` for
    every pair), non-empty lists without duplicates, seeds, ``workers``, ``steps``,
    ``backend`` and ``address``. Then each baseline controller is designed once on the
    env's state version with ``env_kwargs`` (a BallCatcher controller on BallTable, or a
    bad env option, fails here rather than in every episode).

    Raises:
        ValueError: naming the bad value and what is allowed.
    """
    env_id = resolve_env_id(env_id)
    task = task_for(env_id)
    known = ", ".join(task.OBSERVERS)
    observers = _names("observers", observers, known)
    for observer in observers:
        if observer not in task.OBSERVERS:
            raise ValueError(f"unknown observer {observer!r} for {env_id}; allowed: {known}")
    controllers = _names("controllers", controllers, "a controller name or ALGO:DIR")
    for controller in controllers:
        for observer in observers:
            check_controller(controller, env_id, observer)
    seeds = _seeds(seeds)
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be an integer >= 1, got {workers!r}")
    if steps is not None and (isinstance(steps, bool) or not isinstance(steps, int) or steps < 1):
        raise ValueError(f"steps must be an integer >= 1 or None, got {steps!r}")
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; allowed: {', '.join(BACKENDS)}")
    if address is not None and backend != "ray":
        raise ValueError(
            f"address {address!r} is a Ray cluster's address: it needs backend 'ray', "
            f"got {backend!r}"
        )
    if backend == "ray":
        if workers != 1:
            raise ValueError(
                f"workers={workers} applies to the local backend only; with backend 'ray' "
                "the cluster's CPUs decide how many episodes run at once"
            )
        if importlib.util.find_spec("ray") is None:
            raise ValueError(f"backend 'ray' needs Ray, which is not installed: {RAY_INSTALL_HINT}")
    env_kwargs = dict(env_kwargs or {})
    if "obs_mode" in env_kwargs:
        raise ValueError("env_kwargs must not set obs_mode: each observer decides it")
    _check_designs(env_id, controllers, env_kwargs)
    return {
        "env_id": env_id,
        "observers": observers,
        "controllers": controllers,
        "seeds": seeds,
        "env_kwargs": env_kwargs,
    }


def _check_designs(env_id: str, controllers: Sequence[str], env_kwargs: Mapping[str, Any]) -> None:
    """Design every baseline controller once on the state env (trained agents were checked
    against the env by check_controller); ValueError if the env or a design fails."""
    baselines = [c for c in controllers if parse_agent_spec(c) is None]
    if not baselines:
        return
    try:
        env = make_env(env_id, ORACLE, env_kwargs)
    except (TypeError, ValueError) as exc:
        raise ValueError(
            f"cannot make {env_id} with env options {dict(env_kwargs)}: {exc}"
        ) from exc
    try:
        for controller in baselines:
            try:
                build_controller(controller, env)
            except ValueError as exc:
                raise ValueError(f"controller {controller!r} does not fit {env_id}: {exc}") from exc
    finally:
        env.close()


# --- names and command line --------------------------------------------------------------
def safe_name(name: str) -> str:
    """``name`` as a folder name: runs of characters other than letters, digits, ``.``,
    ``_`` and ``-`` become ``-`` (``ppo:runs/x`` -> ``ppo-runs-x``)."""
    return re.sub(r"[^A-Za-z0-9._-]+", "-", name).strip(".-") or "unnamed"


def pair_folders(pairs: Sequence[tuple[str, str]]) -> list[str]:
    """One distinct folder name ``<observer>__<controller>`` per (observer, controller)
    pair (a suffix ``-2``, ``-3``... where two pairs' safe names collide)."""
    folders: list[str] = []
    for observer, controller in pairs:
        base = f"{safe_name(observer)}__{safe_name(controller)}"
        folder, k = base, 1
        while folder in folders:
            k += 1
            folder = f"{base}-{k}"
        folders.append(folder)
    return folders


def format_seeds(seeds: Sequence[int]) -> str:
    """Seeds as ``--seeds`` text: runs of consecutive seeds as ranges (``0-2,5,7-8``)."""
    parts: list[str] = []
    k = 0
    while k < len(seeds):
        j = k
        while j + 1 < len(seeds) and seeds[j + 1] == seeds[j] + 1:
            j += 1
        parts.append(str(seeds[k]) if j == k else f"{seeds[k]}-{seeds[j]}")
        k = j + 1
    return ",".join(parts)


def _option_text(key: str, value: Any) -> str:
    """``KEY=VALUE`` that ``observer_gym.train.cli.env_option`` reads back as ``value``."""
    if isinstance(value, str):
        try:
            same = ast.literal_eval(value) == value
        except (ValueError, SyntaxError):
            same = True  # read back as text
        return f"{key}={value if same else repr(value)}"
    return f"{key}={value!r}"


def command_line(
    env_id: str,
    observers: Sequence[str],
    controllers: Sequence[str],
    seeds: Sequence[int],
    steps: int | None = None,
    workers: int = 1,
    backend: str = "local",
    address: str | None = None,
    env_kwargs: Mapping[str, Any] | None = None,
) -> str:
    """The ``observer-gym compare`` command line that runs this comparison again (without
    ``--out``: it writes a new folder)."""
    words = [
        "observer-gym",
        "compare",
        "--env",
        env_id.split("/", 1)[-1],
        "--observers",
        ",".join(observers),
        "--controllers",
        ",".join(controllers),
        "--seeds",
        format_seeds(seeds),
    ]
    if steps is not None:
        words += ["--steps", str(steps)]
    if workers != 1:
        words += ["--workers", str(workers)]
    if backend != "local":
        words += ["--backend", backend]
    if address is not None:
        words += ["--address", address]
    for key, value in (env_kwargs or {}).items():
        words += ["--env-option", _option_text(key, value)]
    return shlex.join(words)


# --- the comparison ----------------------------------------------------------------------
def run_comparison(
    env_id: str,
    observers: Sequence[str] | str,
    controllers: Sequence[str] | str,
    seeds: Sequence[int],
    out_dir: str | Path,
    workers: int = 1,
    backend: str = "local",
    address: str | None = None,
    steps: int | None = None,
    env_kwargs: Mapping[str, Any] | None = None,
    progress: bool = True,
    cli_args: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Run every (observer, controller) pair on ``seeds``; write tables, plots, results.

    Episode i of every pair resets with ``seeds[i]``. Every input is checked first
    (:func:`check_comparison`); then all episodes run in one batch.

    Writes into ``out_dir`` (created): ``table.md`` (one row per pair: mean ± 95 %
    half-width of each of the task's ``COMPARE_METRICS``, rates with their Wilson
    interval, and, with "oracle" among the observers, the paired difference of the
    primary metric observer − oracle), ``table.csv`` (observer, controller, metric, n,
    mean, half_width, low, high, interval; values in the metric's stored SI unit, rates
    0-1), ``bar_<metric>.png`` per metric, the task's plots of each pair in
    ``pairs/<observer>__<controller>/`` and, last and atomically, ``results.json``.
    Prints the table and the output folder.

    Args:
        env_id: a registered id, with or without ``observer_gym/``.
        observers: names of the task's ``OBSERVERS`` (a string is split at commas).
        controllers: controller names or trained agents ``ALGO:DIR``.
        seeds: distinct reset seeds >= 0, the same for every pair.
        out_dir: the output folder.
        workers: processes for the local backend (>= 1); results do not depend on it.
        backend: "local" or "ray" (Ray tasks; the same results).
        address: the Ray cluster to connect to (backend "ray" only; None: start a local
            Ray instance).
        steps: cap on each episode's steps (None: the env's time limit).
        env_kwargs: extra ``gym.make`` options for every pair (the observer sets obs_mode).
        progress: show a progress bar over episodes.
        cli_args: the command line's arguments, recorded in results.json; when given,
            table.md starts with the command line that regenerates it.

    Returns:
        What ``results.json`` holds (JSON types): ``config``, ``versions``,
        ``wall_time_s``, ``pairs`` (per pair: ``observer``, ``controller``, ``folder``,
        ``episodes`` with each episode's metrics, the task's ``summary``, ``statistics``
        per compared metric, ``vs_oracle``, ``files``), ``starts_match`` and ``files``.

    Raises:
        ValueError: a bad input (see :func:`check_comparison`).
    """
    checked = check_comparison(
        env_id, observers, controllers, seeds, workers, backend, address, steps, env_kwargs
    )
    env_id, observers, controllers = (checked[k] for k in ("env_id", "observers", "controllers"))
    seeds, env_kwargs = checked["seeds"], checked["env_kwargs"]
    task = task_for(env_id)
    metrics = compare_metrics(task)
    primary = next(iter(metrics))
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)

    pairs = [(observer, controller) for controller in controllers for observer in observers]
    specs = [
        EpisodeSpec(env_id, observer, controller, seed, steps, env_kwargs)
        for observer, controller in pairs
        for seed in seeds
    ]
    tic_s = time.perf_counter()
    if backend == "ray":
        from observer_gym.train.ray_backend import run_episodes_ray  # deferred: imports Ray

        records = run_episodes_ray(specs, address=address, progress=progress)
    else:
        records = run_episodes(specs, workers, progress, desc="compare")
    wall_time_s = time.perf_counter() - tic_s

    n = len(seeds)
    by_pair = {pair: records[k * n : (k + 1) * n] for k, pair in enumerate(pairs)}
    extras = getattr(task, "compare_extras", None)
    results_pairs = []
    for (observer, controller), folder in zip(pairs, pair_folders(pairs), strict=True):
        episodes = []
        for i, (seed, record) in enumerate(zip(seeds, by_pair[observer, controller], strict=True)):
            values = task.episode_metrics(record)
            if extras is not None:
                values.update(extras(values))
            episodes.append({"episode": i, "seed": seed, **values})
        results_pairs.append(
            {
                "observer": observer,
                "controller": controller,
                "folder": folder,
                "obs_mode": task.OBSERVERS[observer][0],
                "pipeline_options": task.OBSERVERS[observer][1],
                "controller_config": by_pair[observer, controller][0]["controller"],
                "episodes": episodes,
                "summary": task.summarize(episodes),
                "statistics": {
                    key: metric_statistics([e.get(key) for e in episodes]) for key in metrics
                },
                "vs_oracle": None,
            }
        )
    lookup = {(p["observer"], p["controller"]): p for p in results_pairs}
    if ORACLE in observers:
        for pair in results_pairs:
            if pair["observer"] != ORACLE:
                reference = lookup[ORACLE, pair["controller"]]
                pair["vs_oracle"] = paired_difference(
                    [e.get(primary) for e in pair["episodes"]],
                    [e.get(primary) for e in reference["episodes"]],
                )
    starts_match = all(
        np.array_equal(record["state"][0], records[i % n]["state"][0])
        for i, record in enumerate(records)
    )
    if not starts_match:
        print(
            "observer-gym compare: warning: the pairs' episodes do not all start from the "
            "same state for the same seed; the paired differences are not paired"
        )

    files: list[str] = []
    for pair in results_pairs:
        pair_dir = out_dir / "pairs" / pair["folder"]
        pair_dir.mkdir(parents=True, exist_ok=True)
        names = task.plot(by_pair[pair["observer"], pair["controller"]], pair["observer"], pair_dir)
        pair["files"] = [f"pairs/{pair['folder']}/{name}" for name in names]
        files += pair["files"]
    for key, spec in metrics.items():
        name = f"bar_{key}.png"
        plot_bars(results_pairs, observers, controllers, key, spec, n, out_dir / name)
        files.append(name)

    command = command_line(
        env_id, observers, controllers, seeds, steps, workers, backend, address, env_kwargs
    )
    table = comparison_table(results_pairs, metrics, n)
    write_markdown(out_dir / "table.md", table, metrics, env_id, seeds, steps, command, cli_args)
    write_csv(out_dir / "table.csv", results_pairs, metrics)
    files += ["table.md", "table.csv", "results.json"]

    env_config = dict(records[0]["env_config"])
    env_config.pop("obs_mode", None)  # each pair's is its observer's (pairs[].obs_mode)
    versions = VERSIONED_PACKAGES + ("scipy",) + (("ray",) if backend == "ray" else ())
    results = to_jsonable(
        {
            "config": {
                "env_id": env_id,
                "observers": observers,
                "controllers": controllers,
                "seeds": seeds,
                "episodes": n,
                "steps": steps,
                "env_kwargs": env_kwargs,
                "env_config": env_config,
                "workers": workers,
                "backend": backend,
                "address": address,
                "confidence": CONFIDENCE,
                "primary_metric": primary,
                "metrics": {
                    key: dict(
                        zip(("label", "unit", "scale", "digits", "better"), spec, strict=True)
                    )
                    for key, spec in metrics.items()
                },
                **task.CONFIG,
                "command": command,
                "out_dir": str(out_dir),
                "cli_args": cli_args,
            },
            "versions": package_versions(versions),
            "wall_time_s": wall_time_s,
            "starts_match": starts_match,
            "pairs": results_pairs,
            "files": files,
        }
    )
    write_json_atomic(out_dir / "results.json", results)
    print(
        f"observer-gym compare: {env_id}, {len(observers)} observer(s) x "
        f"{len(controllers)} controller(s), {n} episode(s) each (seeds {format_seeds(seeds)}), "
        f"{backend} backend, {wall_time_s:.1f} s"
    )
    print(table)
    print(f"output: {out_dir}")
    return results


def compare_metrics(task: Any) -> dict[str, tuple[str, str, float, int, str]]:
    """The task's ``COMPARE_METRICS`` (key -> label, unit, scale from the stored value to
    the unit, digits, "lower" or "higher" is better), checked; the first is primary."""
    metrics = dict(getattr(task, "COMPARE_METRICS", {}))
    if not metrics:
        raise ValueError(f"task {task.__name__} defines no COMPARE_METRICS")
    for key, spec in metrics.items():
        if len(spec) != 5 or spec[4] not in BETTER:
            raise ValueError(
                f"{task.__name__}.COMPARE_METRICS[{key!r}] must be (label, unit, scale, "
                f"digits, 'lower' or 'higher'), got {spec!r}"
            )
    return metrics


# --- outputs -----------------------------------------------------------------------------
def _number(value: float, digits: int) -> str:
    return f"{value:.{digits}f}"


def format_statistic(stat: Mapping[str, Any], scale: float, digits: int, episodes: int) -> str:
    """A table cell: "mean ± half-width", a rate as "rate [low, high]", "n/a" without a
    value, and "(n=k)" when fewer than all ``episodes`` have a value."""
    if stat["n"] == 0 or stat["mean"] is None:
        return "n/a"
    mean = _number(stat["mean"] * scale, digits)
    if stat["method"] == "wilson":
        low, high = (_number(stat[k] * scale, digits) for k in ("low", "high"))
        text = f"{mean} [{low}, {high}]"
    elif stat["half_width"] is None:
        text = mean
    else:
        text = f"{mean} ± {_number(stat['half_width'] * scale, digits)}"
    if stat["n"] < episodes:
        text += f" (n={stat['n']})"
    return text


def format_difference(diff: Mapping[str, Any], scale: float, digits: int, episodes: int) -> str:
    """The "vs oracle" cell: "+mean ± half-width (×ratio)", "(n=k)" if fewer episodes."""
    if diff["n"] == 0 or diff["mean"] is None:
        return "n/a"
    text = f"{diff['mean'] * scale:+.{digits}f}"
    if diff["half_width"] is not None:
        text += f" ± {_number(diff['half_width'] * scale, digits)}"
    if diff["ratio"] is not None:
        text += f" (×{diff['ratio']:.2f})"
    if diff["n"] < episodes:
        text += f" (n={diff['n']})"
    return text


def _header(label: str, unit: str, better: str | None = None) -> str:
    text = f"{label} ({unit})" if unit else label
    return f"{text} {'↓' if better == 'lower' else '↑'}" if better else text


def difference_unit(unit: str) -> str:
    """The unit of a difference: percentage points for a percentage."""
    return "pp" if unit == "%" else unit


def comparison_table(
    pairs: Sequence[Mapping[str, Any]],
    metrics: Mapping[str, tuple[str, str, float, int, str]],
    episodes: int,
) -> str:
    """The Markdown table: one row per pair, a column per metric and, when some pair has a
    ``vs_oracle``, the column of the primary metric's paired difference from the oracle."""
    primary = next(iter(metrics))
    label, unit, scale, digits, _ = metrics[primary]
    with_oracle = any(p["vs_oracle"] is not None for p in pairs)
    headers = ["observer", "controller"]
    headers += [_header(lab, u, better) for lab, u, _, _, better in metrics.values()]
    if with_oracle:
        headers.append(_header(f"Δ {label} vs oracle", difference_unit(unit)))
    rows = []
    for pair in pairs:
        row = [pair["observer"], pair["controller"]]
        for key, (_, _, sc, dg, _) in metrics.items():
            row.append(format_statistic(pair["statistics"][key], sc, dg, episodes))
        if with_oracle:
            diff = pair["vs_oracle"]
            row.append(
                "reference"
                if pair["observer"] == ORACLE
                else "n/a"
                if diff is None
                else format_difference(diff, scale, digits, episodes)
            )
        rows.append(row)
    return format_table(headers, rows)


def write_markdown(
    path: Path,
    table: str,
    metrics: Mapping[str, tuple[str, str, float, int, str]],
    env_id: str,
    seeds: Sequence[int],
    steps: int | None,
    command: str,
    cli_args: Mapping[str, Any] | None,
) -> None:
    """``table.md``: the command line (when run from it), what was run, the table, a key."""
    primary_label = next(iter(metrics.values()))[0]
    lines = [f"`{command}`", ""] if cli_args is not None else []
    lines += [
        f"{env_id}: {len(seeds)} episode(s) per pair, seeds {format_seeds(seeds)} "
        f"(episode i of every pair has the same seed), "
        + (f"at most {steps} steps each." if steps else "each to the env's end."),
        "",
        table,
        "",
        f"Cells: mean ± {PERCENT} half-width (Student t) over the episodes with a "
        f"value, (n=k) when fewer than all; rates: rate [{PERCENT} Wilson interval]. "
        "↓ lower is better, ↑ higher is better. "
        f"Δ vs oracle: observer − oracle of {primary_label}, episode by episode on the same "
        f"seeds, mean ± {PERCENT} half-width (Student t), and (×) the ratio of the "
        "means.",
        "",
    ]
    path.write_text("\n".join(lines), encoding="utf-8")


CSV_COLUMNS = ("observer", "controller", "metric", "n", "mean", "half_width", "low", "high")


def write_csv(
    path: Path,
    pairs: Sequence[Mapping[str, Any]],
    metrics: Mapping[str, tuple[str, str, float, int, str]],
) -> None:
    """``table.csv``: one row per pair and metric (stored SI values, rates 0-1), and one
    per pair with an oracle difference (metric ``<primary>_minus_oracle``); empty cells
    for undefined numbers; ``interval`` says how the interval was computed."""
    primary = next(iter(metrics))
    with path.open("w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f)
        writer.writerow([*CSV_COLUMNS, "interval"])

        def row(pair: Mapping[str, Any], metric: str, stat: Mapping[str, Any]) -> None:
            numbers = ["" if stat[k] is None else repr(float(stat[k])) for k in CSV_COLUMNS[4:]]
            writer.writerow(
                [pair["observer"], pair["controller"], metric, stat["n"], *numbers, stat["method"]]
            )

        for pair in pairs:
            for key in metrics:
                row(pair, key, pair["statistics"][key])
            if pair["vs_oracle"] is not None:
                row(pair, f"{primary}_minus_oracle", pair["vs_oracle"])


def plot_bars(
    pairs: Sequence[Mapping[str, Any]],
    observers: Sequence[str],
    controllers: Sequence[str],
    key: str,
    spec: tuple[str, str, float, int, str],
    episodes: int,
    path: Path,
) -> None:
    """A grouped bar chart of one metric: controllers on the x axis, one bar per observer,
    error bars the 95 % interval (t or Wilson); a bar with fewer episodes than all is
    labelled n=k, a pair without a value n/a."""
    label, unit, scale, _, better = spec
    lookup = {(p["observer"], p["controller"]): p["statistics"][key] for p in pairs}
    fig = new_figure((max(5.0, 1.2 + 0.6 * len(controllers) * len(observers)), 4.0))
    ax = fig.add_subplot()
    x = np.arange(len(controllers))
    width = 0.8 / len(observers)
    for j, observer in enumerate(observers):
        heights, below, above, counts = [], [], [], []
        for controller in controllers:
            stat = lookup[observer, controller]
            mean = np.nan if stat["mean"] is None else stat["mean"] * scale
            heights.append(mean)
            counts.append("" if stat["n"] == episodes else f"n={stat['n']}")
            if stat["low"] is None:
                below.append(0.0)
                above.append(0.0)
            else:
                below.append(mean - stat["low"] * scale)
                above.append(stat["high"] * scale - mean)
        positions = x + (j - (len(observers) - 1) / 2) * width
        bars = ax.bar(
            positions,
            heights,
            width,
            yerr=[below, above],
            capsize=3,
            color=f"C{j % 10}",
            label=observer,
        )
        ax.bar_label(bars, labels=counts, label_type="center", fontsize=7)
        for position, height in zip(positions, heights, strict=True):
            if np.isnan(height):
                ax.text(position, 0.0, "n/a", ha="center", va="bottom", fontsize=7)
    ax.set_xticks(x, controllers)
    ax.set_xlim(-0.5, len(controllers) - 0.5)
    ax.set_xlabel("controller")
    ax.set_ylabel(f"{label} ({unit})" if unit else label)
    ax.set_title(
        f"{label} ({better} is better)\nmean and {PERCENT} interval, {episodes} episode(s)",
        fontsize=9,
    )
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(title="observer", fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.savefig(path, dpi=DPI)
