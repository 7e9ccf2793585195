"""The cost per episode of ``observer-gym train --randomize``: the world rebuilt at every
reset with drawn options, against the same training env with fixed options.

    .venv/bin/python benchmarks/bench_randomize.py --episodes 40

For each system (BallCatcher-v1, TargetFollower-v0, BallTable-v0) the training env of
``train --algo ppo --obs estimate`` (its YAML's env options and feature set, the default
estimating observer on measurements) is built twice: with the fixed options, and as a
:class:`~observer_gym.train.rl.randomize.RandomizedEnv` drawing the benchmark suite v1's
level ranges (every option that differs between the levels: a number from the ideal
level's value to the field level's, a categorical one from both). Each runs ``--episodes``
episodes of uniform random actions (the first reset seeded with ``--seed``); the table
gives the mean time of a reset (which in the randomised env closes the world and builds a
new one, observer stack included) and of a whole episode, and the reset's extra time per
episode, with the load average at the start and the end (the machine is shared).

The randomised episodes' steps differ from the fixed ones' (other latencies, frame drops,
drag), so the overhead of the randomisation is the reset's difference, not the episodes'.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path
from typing import Any

from observer_gym.envs import system_for_id
from observer_gym.train.rl.agent_env import make_agent_env
from observer_gym.train.rl.hyperparams import resolve_hyperparams
from observer_gym.train.rl.randomize import check_randomize

SUITES = Path(__file__).parent.parent / "train" / "experiments" / "benchmark" / "suites" / "v1"
SYSTEMS = {
    "BallCatcher-v1": "ball_catcher",
    "TargetFollower-v0": "target_follower",
    "BallTable-v0": "ball_table",
}


def level_ranges(env_id: str, suite: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The randomisation of the suite's levels: every option that differs between them, a
    number from the ideal level's value (the env's default if it sets none) to the field
    level's, anything else a choice of the two."""
    import dataclasses

    config_class = system_for_id(env_id).env_class().config_class
    defaults = {f.name: f.default for f in dataclasses.fields(config_class)}
    levels = suite["levels"]
    keys = sorted({k for level in levels.values() for k in level["env_options"]})
    ranges: dict[str, dict[str, Any]] = {}
    for key in keys:
        ideal = levels["ideal"]["env_options"].get(key, defaults[key])
        field = levels["field"]["env_options"].get(key, defaults[key])
        if ideal == field:
            continue
        if isinstance(ideal, bool) or not isinstance(ideal, int | float):
            ranges[key] = {"choices": [ideal, field]}
        else:
            ranges[key] = {"low": ideal, "high": field}
    return ranges


def timed_episodes(env: Any, episodes: int, seed: int) -> tuple[list[float], list[float], int]:
    """(reset times, episode times, steps) of ``episodes`` episodes of random actions."""
    env.action_space.seed(seed)
    resets, totals, steps = [], [], 0
    for k in range(episodes):
        tic = time.perf_counter()
        env.reset(seed=seed if k == 0 else None)
        resets.append(time.perf_counter() - tic)
        done = False
        while not done:
            _, _, terminated, truncated, _ = env.step(env.action_space.sample())
            steps += 1
            done = terminated or truncated
        totals.append(time.perf_counter() - tic)
    return resets, totals, steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=40)
    parser.add_argument("--seed", type=int, default=1_000_000)
    parser.add_argument("--envs", default=",".join(SYSTEMS))
    args = parser.parse_args()
    print(f"load average at the start: {os.getloadavg()[0]:.2f}")
    print(
        "| env | randomised options | reset fixed (ms) | reset randomised (ms) | "
        "extra per episode (ms) | episode fixed (ms) | episode randomised (ms) | "
        "steps per episode (fixed / randomised) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for env_id in args.envs.split(","):
        suite = json.loads((SUITES / f"{SYSTEMS[env_id]}.json").read_text())
        params = resolve_hyperparams(env_id, "ppo", "estimate")
        fixed = params["env_kwargs"]
        ranges = check_randomize(env_id, "measurements", fixed, level_ranges(env_id, suite))
        rows = {}
        for name, randomize in (("fixed", None), ("randomised", ranges)):
            env = make_agent_env(
                system_for_id(env_id).env_id,
                "estimate",
                "measurements",
                fixed,
                params["image"],
                None,
                params["features"],
                randomize,
            )
            try:
                rows[name] = timed_episodes(env, args.episodes, args.seed)
            finally:
                env.close()
        (r0, t0, s0), (r1, t1, s1) = rows["fixed"], rows["randomised"]
        m = 1000.0
        extra = statistics.mean(r1) - statistics.mean(r0)
        print(
            f"| {env_id} | {len(ranges)} | {statistics.mean(r0) * m:.1f} | "
            f"{statistics.mean(r1) * m:.1f} | {extra * m:.1f} | "
            f"{statistics.mean(t0) * m:.0f} | {statistics.mean(t1) * m:.0f} | "
            f"{s0 / args.episodes:.0f} / {s1 / args.episodes:.0f} |"
        )
    print(f"load average at the end: {os.getloadavg()[0]:.2f}; {args.episodes} episodes each")


if __name__ == "__main__":
    main()
