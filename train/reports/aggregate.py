"""Scores across seeds, as benchmark papers report them, with rliable's statistics
(Agarwal et al., 2021) computed in NumPy and SciPy
(:mod:`observer_gym.train.reports.bootstrap`, which reproduces rliable's numbers to the
last bit): the interquartile mean (IQM: the mean of the middle 50 % of the scores) with a
stratified-bootstrap 95 % interval (percentile method), seeded.

- :func:`across_seeds`: one score per seed (an agent's final evaluation return, or its
  mean of a metric over the same episodes) -> :class:`SeedStatistics`;
- :func:`aggregate_runs`: the aggregate of a multi-seed training folder
  (``train --seeds``): ``learning_curves.png`` (the mean evaluation return across seeds
  against env steps with its 95 % bootstrap band, each seed's curve behind it),
  ``aggregate.json`` and ``aggregate.md`` (the final scores, their IQM and interval).

With fewer than four seeds the 25 % trimming removes none, so the IQM equals the mean; the
bootstrap of a handful of seeds gives a narrow interval, which says little: report many
seeds. Nothing here needs rliable.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from observer_gym.envs.json_file import read_json
from observer_gym.train.reports.bootstrap import (
    BOOTSTRAP_SEED,
    CONFIDENCE,
    interval_estimates,
    iqm,
    mean_of_task_means,
)
from observer_gym.train.reports.outputs import (
    format_table,
    output_set,
    package_versions,
    write_json_atomic,
)

FINAL_REPS = 10_000  # bootstrap replications of a final score's interval
CURVE_REPS = 2_000  # per evaluation point of the learning curve's band
METHOD = "IQM (25 % trimmed mean) with a stratified-bootstrap percentile interval (rliable)"
AGGREGATE_JSON = "aggregate.json"
AGGREGATE_MD = "aggregate.md"
CURVES_PNG = "learning_curves.png"


def _interval_estimates(scores: np.ndarray, function: Any, reps: int) -> tuple[Any, np.ndarray]:
    """The point estimate and (2, ...) interval of ``function`` over ``scores`` (runs x
    tasks [x points]), bootstrapped ``reps`` times with seed :data:`BOOTSTRAP_SEED`
    (:func:`~observer_gym.train.reports.bootstrap.interval_estimates`: rliable's numbers):
    the same scores give the same interval; the caller's random state is not touched."""
    return interval_estimates(scores, function, reps, CONFIDENCE, BOOTSTRAP_SEED)


@dataclasses.dataclass(frozen=True)
class SeedStatistics:
    """One score per seed and what they give across seeds (in the scores' unit)."""

    seeds: tuple[int, ...]
    scores: tuple[float, ...]
    mean: float
    iqm: float
    iqm_low: float  # the IQM's 95 % stratified-bootstrap interval
    iqm_high: float
    reps: int  # bootstrap replications
    confidence: float = CONFIDENCE
    method: str = METHOD

    def as_dict(self) -> dict[str, Any]:
        """The fields as JSON types."""
        return {**dataclasses.asdict(self), "seeds": list(self.seeds), "scores": list(self.scores)}


def across_seeds(scores: Mapping[int, float], reps: int = FINAL_REPS) -> SeedStatistics:
    """The mean and the IQM with its 95 % stratified-bootstrap interval (rliable's
    method and numbers) of ``scores`` (seed -> score), by seed.

    Raises:
        ValueError: no score, or one that is not a finite number.
    """
    if not scores:
        raise ValueError("scores across seeds need at least one seed's score, got none")
    seeds = tuple(sorted(scores))
    values = np.array([scores[seed] for seed in seeds], dtype=float)
    if not np.all(np.isfinite(values)):
        raise ValueError(
            f"scores must be finite numbers, got {dict(zip(seeds, values.tolist(), strict=True))}"
        )
    if isinstance(reps, bool) or not isinstance(reps, int) or reps < 1:
        raise ValueError(f"reps must be an integer >= 1, got {reps!r}")
    point, interval = _interval_estimates(values[:, None], lambda x: np.array([iqm(x)]), reps)
    return SeedStatistics(
        seeds=seeds,
        scores=tuple(values.tolist()),
        mean=float(np.mean(values)),
        iqm=float(point[0]),
        iqm_low=float(interval[0, 0]),
        iqm_high=float(interval[1, 0]),
        reps=reps,
    )


def statistics_text(stats: SeedStatistics, scale: float = 1.0, digits: int = 1) -> str:
    """``IQM x [low, high], mean y, n seeds``, the values times ``scale``."""

    def number(value: float) -> str:
        return f"{value * scale:.{digits}f}"

    return (
        f"IQM {number(stats.iqm)} [{number(stats.iqm_low)}, {number(stats.iqm_high)}], "
        f"mean {number(stats.mean)}, {len(stats.seeds)} seed(s)"
    )


# --- learning curves ---------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class EvalCurve:
    """One run's evaluation curve (its ``eval.csv``): the deterministic policy's mean
    return over the evaluation episodes at each evaluation's env step count."""

    seed: int
    timesteps: tuple[int, ...]
    return_mean: tuple[float, ...]


def read_eval_curve(run_dir: str | Path, seed: int) -> EvalCurve | None:
    """The curve in ``run_dir/eval.csv`` (None if the run has not evaluated yet); a
    timestep evaluated twice (a resumed run) keeps its last row. ValueError naming the
    file if it is not a curve (a row of another width, a missing column, a value that is
    not a number)."""
    path = Path(run_dir) / "eval.csv"
    if not path.is_file():
        return None
    try:
        rows = np.genfromtxt(path, delimiter=",", names=True, ndmin=1)
        if rows.size == 0:
            return None
        steps_col, returns_col = rows["timesteps"], rows["return_mean"]
    except (ValueError, TypeError) as exc:  # a row of other width, no such column, no header
        raise ValueError(f"{path} is not an evaluation curve: {exc}") from None
    if not (np.all(np.isfinite(steps_col)) and np.all(np.isfinite(returns_col))):
        raise ValueError(f"{path} is not an evaluation curve: a value is not a number")
    by_step = dict(zip(steps_col.astype(int).tolist(), returns_col.tolist(), strict=True))
    steps = tuple(sorted(by_step))
    return EvalCurve(seed, steps, tuple(float(by_step[s]) for s in steps))


@dataclasses.dataclass(frozen=True)
class CurveBand:
    """The mean evaluation return across seeds at the env step counts every seed was
    evaluated at, with its 95 % stratified-bootstrap interval (rliable) at each."""

    timesteps: tuple[int, ...]
    mean: tuple[float, ...]
    low: tuple[float, ...]
    high: tuple[float, ...]
    reps: int

    def as_dict(self) -> dict[str, Any]:
        return {
            k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self).items()
        }


def curve_band(curves: Sequence[EvalCurve], reps: int = CURVE_REPS) -> CurveBand:
    """The band of :class:`CurveBand` over ``curves`` (empty when they share no
    evaluation point, which a warning reports)."""
    common = sorted(set.intersection(*(set(c.timesteps) for c in curves))) if curves else []
    if not common:
        if curves:
            warnings.warn(
                "the seeds' evaluation curves share no env step count; no band drawn",
                stacklevel=2,
            )
        return CurveBand((), (), (), (), reps)
    table = np.array(
        [[dict(zip(c.timesteps, c.return_mean, strict=True))[s] for s in common] for c in curves],
        dtype=float,
    )

    def means(x: np.ndarray) -> np.ndarray:  # x: seeds x 1 task x points
        return np.array([mean_of_task_means(x[..., j]) for j in range(x.shape[-1])])

    point, interval = _interval_estimates(table[:, None, :], means, reps)
    return CurveBand(
        tuple(common),
        tuple(point.tolist()),
        tuple(interval[0].tolist()),
        tuple(interval[1].tolist()),
        reps,
    )


def plot_learning_curves(
    curves: Sequence[EvalCurve], band: CurveBand, path: Path, title: str
) -> None:
    """Each seed's evaluation curve (thin) and the mean across seeds with its 95 %
    bootstrap band, against env steps."""
    from observer_gym.train.core.plots import new_figure, save_figure  # deferred: matplotlib

    fig = new_figure((7.5, 4.5))
    ax = fig.subplots()
    for k, curve in enumerate(curves):
        ax.plot(
            curve.timesteps,
            curve.return_mean,
            color="0.6",
            lw=0.8,
            alpha=0.8,
            label="each seed" if k == 0 else None,
        )
    if band.timesteps:
        ax.fill_between(
            band.timesteps,
            band.low,
            band.high,
            color="tab:blue",
            alpha=0.25,
            lw=0,
            label=f"{CONFIDENCE * 100:g} % bootstrap interval",
        )
        ax.plot(band.timesteps, band.mean, color="tab:blue", lw=2, marker="o", ms=3, label="mean")
    ax.set(xlabel="env steps", ylabel="evaluation return (deterministic policy)", title=title)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    save_figure(fig, path)


# --- the aggregate of a multi-seed training folder -------------------------------------------
@dataclasses.dataclass(frozen=True)
class Aggregate:
    """What ``aggregate.json`` holds: the runs, their final evaluation returns across
    seeds and the learning curves' band."""

    env_id: str
    algo: str
    obs: str
    observer: str
    final_return: SeedStatistics  # each seed's last evaluation (its final policy)
    final_timesteps: dict[int, int]  # the env steps each seed's last evaluation came at
    eval_episodes: dict[int, int]  # episodes per evaluation, per seed
    curve: CurveBand
    files: tuple[str, ...]

    def as_dict(self) -> dict[str, Any]:
        return {
            "env_id": self.env_id,
            "algo": self.algo,
            "obs": self.obs,
            "observer": self.observer,
            "final_return": self.final_return.as_dict(),
            "final_timesteps": {str(k): v for k, v in self.final_timesteps.items()},
            "eval_episodes": {str(k): v for k, v in self.eval_episodes.items()},
            "curve": self.curve.as_dict(),
            "files": list(self.files),
            "versions": package_versions(("observer-gym", "numpy", "scipy", "stable-baselines3")),
        }


def aggregate_runs(
    out_dir: str | Path,
    runs: Mapping[int, Path],
    configs: Mapping[int, Mapping[str, Any]],
    reps: int = FINAL_REPS,
    curve_reps: int = CURVE_REPS,
) -> Aggregate:
    """Aggregate the seed runs ``runs`` (seed -> run folder, each with its ``eval.csv``)
    of the multi-seed folder ``out_dir``, trained with ``configs`` (seed -> the run's
    config; :func:`observer_gym.train.rl.seeds.aggregate_seeds` reads both): writes
    ``learning_curves.png``, ``aggregate.md`` and, last, ``aggregate.json`` into
    ``out_dir`` as a set (all or none: :func:`~observer_gym.train.reports.outputs.output_set`),
    and returns what the JSON holds.

    Raises:
        ValueError: no seed runs in ``out_dir``, runs of different envs, algorithms or
            observations, or a run that has not evaluated yet.
    """
    out_dir = Path(out_dir)
    if not runs:
        raise ValueError(f"{out_dir} holds no seed_<s>/ runs to aggregate")
    kinds = {(c["env_id"], c["algo"], c["obs"], c["observer"]) for c in configs.values()}
    if len(kinds) > 1:
        raise ValueError(f"the runs in {out_dir} differ in env, algo or obs: {sorted(kinds)}")
    curves = []
    for seed, path in runs.items():
        curve = read_eval_curve(path, seed)
        if curve is None:
            raise ValueError(f"{path} has no evaluation yet (no eval.csv) to aggregate")
        curves.append(curve)
    env_id, algo, obs, observer = kinds.pop()
    final = across_seeds({c.seed: c.return_mean[-1] for c in curves}, reps)
    band = curve_band(curves, curve_reps)
    title = f"{algo.upper()} on {env_id}, obs {obs}: {len(curves)} seeds"
    aggregate = Aggregate(
        env_id=env_id,
        algo=algo,
        obs=obs,
        observer=observer,
        final_return=final,
        final_timesteps={c.seed: c.timesteps[-1] for c in curves},
        eval_episodes={s: int(c["hyperparams"]["eval_episodes"]) for s, c in configs.items()},
        curve=band,
        files=(CURVES_PNG, AGGREGATE_MD, AGGREGATE_JSON),
    )
    with output_set(out_dir, last=(AGGREGATE_JSON,)) as staging:  # all three or none
        plot_learning_curves(curves, band, staging / CURVES_PNG, title)
        (staging / AGGREGATE_MD).write_text(aggregate_markdown(aggregate), encoding="utf-8")
        write_json_atomic(staging / AGGREGATE_JSON, aggregate.as_dict())
    return aggregate


def aggregate_markdown(aggregate: Aggregate) -> str:
    """``aggregate.md``: what was trained, each seed's final return, and across seeds the
    mean and the IQM with its interval."""
    final = aggregate.final_return
    rows = [
        [str(seed), str(aggregate.final_timesteps[seed]), f"{score:.2f}"]
        for seed, score in zip(final.seeds, final.scores, strict=True)
    ]
    per_seed = format_table(["seed", "env steps", "final evaluation return"], rows)
    summary = format_table(
        ["seeds", "mean", "IQM", f"IQM {CONFIDENCE * 100:g} % interval"],
        [
            [
                str(len(final.seeds)),
                f"{final.mean:.2f}",
                f"{final.iqm:.2f}",
                f"[{final.iqm_low:.2f}, {final.iqm_high:.2f}]",
            ]
        ],
    )
    episodes = sorted(set(aggregate.eval_episodes.values()))
    return "\n".join(
        [
            f"# {aggregate.algo.upper()} on {aggregate.env_id}, obs {aggregate.obs} "
            f"(observer {aggregate.observer})",
            "",
            "Final evaluation return of each seed: its final policy, deterministic, mean over "
            f"{'/'.join(map(str, episodes))} evaluation episode(s) (eval.csv's last row).",
            "",
            per_seed,
            "",
            summary,
            "",
            f"{METHOD}, {final.reps} replications. With fewer than 4 seeds the IQM is the "
            "mean. Learning curves: learning_curves.png.",
            "",
        ]
    )


def read_aggregate(out_dir: str | Path) -> dict[str, Any] | None:
    """The ``aggregate.json`` of a multi-seed folder, None if it has none yet."""
    path = Path(out_dir) / AGGREGATE_JSON
    return read_json(path) if path.is_file() else None
