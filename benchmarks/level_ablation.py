"""Which of a benchmark level's options costs an entry its score: the level's headline
metric with each option alone (on the ideal level's options) and with each option left
out (the rest of the level kept), on the level's first official seeds.

    .venv/bin/python benchmarks/level_ablation.py --env BallCatcher-v1 --level lab \
        --observer kf-measurements --controller intercept --episodes 100 --workers 2

It prints one table: the level itself, the ideal level, then per option "alone" and
"left out", each with the mean of the metric and its 95 % interval
(Student t's, or Wilson's for a 0/1 metric such as BallCatcher's ``caught``). The
episodes run exactly as a benchmark entry's
(:func:`observer_gym.train.experiments.benchmark.references.episode_values`); a trained
agent (``--controller ALGO:DIR`` or ``ALGO:NAME``) gets the env options it was trained
with under each row's, as in ``observer-gym benchmark`` (a row's option wins), and, if
they scale the camera, each row's pixel-valued options times the scale and a metric in
pixels in the default camera's pixels
(:mod:`observer_gym.train.experiments.camera_scale`).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from observer_gym.train.experiments.benchmark.references import episode_values
from observer_gym.train.experiments.benchmark.run import agent_entry
from observer_gym.train.experiments.benchmark.suite import DEFAULT_VERSION, load_suite
from observer_gym.train.experiments.camera_scale import camera_scale, options_in_entry_pixels
from observer_gym.train.reports.compare_stats import mean_interval, rate_interval
from observer_gym.train.rl.run_dir import parse_agent_spec


def interval(values: np.ndarray) -> tuple[float, float]:
    """95 % interval of the mean: Wilson's for 0/1 values, else Student t's
    (train/reports/compare_stats.py, as ``compare`` reports them)."""
    if np.all((values == 0.0) | (values == 1.0)):
        stat = rate_interval([bool(v) for v in values])
    else:
        stat = mean_interval(values.tolist())
    return stat["low"], stat["high"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", required=True)
    parser.add_argument("--level", required=True)
    parser.add_argument("--observer", required=True)
    parser.add_argument("--controller", default=None, help="default: the suite's reference")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--suite", default=DEFAULT_VERSION)
    args = parser.parse_args()
    suite = load_suite(args.env, args.suite)
    levels = {level.name: level for level in suite.levels}
    if args.level not in levels:
        parser.error(f"level {args.level!r} is not in suite {suite.version}: {', '.join(levels)}")
    level = levels[args.level]
    ideal = suite.levels[0].env_options
    controller = args.controller or suite.controller
    seeds = level.seeds(args.episodes)
    # an agent's own env options (an rgb agent's image size) under each row's
    agent_options = agent_entry(controller).env_options if parse_agent_spec(controller) else {}
    scale = camera_scale(suite.env_id, agent_options)
    rows = [(f"level {level.name}", dict(level.env_options)), (f"{suite.levels[0].name}", ideal)]
    for key, value in level.env_options.items():
        rows.append((f"{key}={value} alone", {**ideal, key: value}))
        rows.append((f"{key} left out", {k: v for k, v in level.env_options.items() if k != key}))
    print(
        f"{suite.env_id} suite {suite.version}, level {level.name}'s first {len(seeds)} seeds: "
        f"{args.observer} + {controller}, metric {suite.metric.name} ({suite.metric.better} "
        f"is better); the agent's own env options under each row's: {agent_options or 'none'}, "
        f"its camera's scale {scale:.6g}"
    )
    print("| options | mean | 95 % interval |")
    print("|---|---|---|")
    tic = time.perf_counter()
    for name, options in rows:
        in_entry_pixels = {**agent_options, **options_in_entry_pixels(options, scale)}
        values = episode_values(
            suite, level._replace(env_options=in_entry_pixels), args.observer,
            controller, seeds, args.workers,
        )  # fmt: skip
        values = np.asarray(values)  # a metric in pixels: the default camera's (the task's)
        low, high = interval(values)
        print(f"| {name} | {values.mean():.3f} | [{low:.3f}, {high:.3f}] |", flush=True)
    print(f"({time.perf_counter() - tic:.0f} s of wall time)")


if __name__ == "__main__":
    main()
