"""Measure a benchmark suite's reference values and write them into its suite file.

    .venv/bin/python benchmarks/benchmark_references.py --env BallTable-v0 --workers 2

For every level of the system's suite (``train/experiments/benchmark/suites/<version>/``)
it runs, on the level's official seeds: the oracle observer with the reference
controller (score 1), the raw camera baseline (``floor_observer``, no filter) with the
reference controller, and the idle controller (the zero action) on the oracle, and
writes each one's mean of the headline metric into the file's ``references`` (with
``references_command``: this command). It prints, per level and baseline, the mean and
the per-episode standard deviation of the metric and of the normalised score (what
docs/benchmark.md's episode counts come from). The references do not depend on any
filter: neither baseline uses one.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from observer_gym.train.experiments.benchmark.idle import Idle  # noqa: F401  (importable)
from observer_gym.train.experiments.benchmark.records import metric_value
from observer_gym.train.experiments.benchmark.score import normalised
from observer_gym.train.experiments.benchmark.suite import (
    DEFAULT_VERSION,
    References,
    load_suite,
    suite_path,
)
from observer_gym.train.experiments.episode import EpisodeSpec, iter_episodes
from observer_gym.train.experiments.sweep import sweep_episode

IDLE = "observer_gym.train.experiments.benchmark.idle:make_idle"


def measure(
    env_id: str,
    observer: str,
    controller: str,
    env_options: dict,
    seeds: list[int],
    metric: str,
    workers: int,
) -> np.ndarray:
    specs = [
        EpisodeSpec.of(env_id, observer, controller, seed, env_kwargs=env_options) for seed in seeds
    ]
    values = np.zeros(len(specs))
    for index, episode in iter_episodes(specs, workers, sweep_episode):
        values[index] = metric_value(
            episode["metrics"].get(metric), metric, f"seed {specs[index].seed}"
        )
    return values


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", required=True)
    parser.add_argument("--suite", default=DEFAULT_VERSION)
    parser.add_argument("--workers", type=int, default=1)
    args = parser.parse_args()
    suite = load_suite(args.env, args.suite)
    path = suite_path(suite.version, suite.system)
    data = json.loads(path.read_text())
    metric = suite.metric.name
    for level in suite.levels:
        seeds = level.seeds(suite.episodes)
        tic = time.perf_counter()
        runs = {
            "oracle": measure(
                suite.env_id,
                "oracle",
                suite.controller,
                level.env_options,
                seeds,
                metric,
                args.workers,
            ),
            "raw": measure(
                suite.env_id,
                suite.floor_observer,
                suite.controller,
                level.env_options,
                seeds,
                metric,
                args.workers,
            ),
            "idle": measure(
                suite.env_id, "oracle", IDLE, level.env_options, seeds, metric, args.workers
            ),
        }
        refs = References(*(float(np.mean(runs[k])) for k in ("oracle", "raw", "idle")), len(seeds))
        data["levels"][level.name]["references"] = refs._asdict()
        floor = refs.floor(suite.metric.better)
        print(
            f"{suite.system.short_id} {level.name}: floor {floor[0]} "
            f"({time.perf_counter() - tic:.0f} s)"
        )
        for name, values in runs.items():
            scores = normalised(values, refs, suite.metric.better)
            print(
                f"  {name:6s} {metric} mean {np.mean(values):.6g} sd {np.std(values, ddof=1):.4g}"
                f" | score mean {np.mean(scores):.3f} sd {np.std(scores, ddof=1):.3f}"
            )
    data["references_command"] = (
        f"python benchmarks/benchmark_references.py --env {suite.system.short_id} "
        f"--suite {suite.version} --workers {args.workers}"
    )
    path.write_text(json.dumps(data, indent=2) + "\n")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
