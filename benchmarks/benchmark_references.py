"""Measure a benchmark suite's reference values and write them into its suite file.

    .venv/bin/python benchmarks/benchmark_references.py --env BallTable-v0 --workers 2

For every level of the system's suite (``train/experiments/benchmark/suites/<version>/``)
it runs, on the level's official seeds, the oracle observer with the reference
controller (score 1), the raw camera baseline (``floor_observer``, no filter) with the
reference controller, and the idle controller (the zero action) on the oracle
(:func:`observer_gym.train.experiments.benchmark.references.measure_level`), and writes
each one's mean of the headline metric into the file's ``references`` (and
``references_command``: this command). It prints, per level and baseline, the mean and
the per-episode standard deviation of the metric and of the normalised score (what
docs/benchmark.md's episode counts come from).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from observer_gym.train.experiments.benchmark.references import measure_level
from observer_gym.train.experiments.benchmark.score import normalised
from observer_gym.train.experiments.benchmark.suite import DEFAULT_VERSION, load_suite, suite_path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", required=True)
    parser.add_argument("--suite", default=DEFAULT_VERSION)
    parser.add_argument("--workers", type=int, default=1)
    args = parser.parse_args()
    suite = load_suite(args.env, args.suite)
    path = suite_path(suite.version, suite.system)
    data = json.loads(path.read_text())
    for level in suite.levels:
        tic = time.perf_counter()
        measured = measure_level(suite, level, args.workers)
        refs = measured.references
        data["levels"][level.name]["references"] = refs._asdict()
        floor = refs.floor(suite.metric.better)[0]
        took_s = time.perf_counter() - tic
        print(f"{suite.system.short_id} {level.name}: floor {floor} ({took_s:.0f} s)", flush=True)
        for name in ("oracle", "raw", "idle"):
            values = getattr(measured, name)
            scores = normalised(values, refs, suite.metric.better)
            print(
                f"  {name:6s} {suite.metric.name} mean {np.mean(values):.6g} "
                f"sd {np.std(values, ddof=1):.4g} | score mean {np.mean(scores):.3f} "
                f"sd {np.std(scores, ddof=1):.3f}",
                flush=True,
            )
    data["references_command"] = (
        f"python benchmarks/benchmark_references.py --env {suite.system.short_id} "
        f"--suite {suite.version} --workers {args.workers}"
    )
    path.write_text(json.dumps(data, indent=2) + "\n")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
