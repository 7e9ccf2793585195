"""How many times one small compare looks its system, task and observer up again by name:

    python benchmarks/request_lookups.py

``observer_gym.compare`` of BallTable-v0 with two observers (``kf-measurements``,
``oracle``) and ``lqr``, one seed, five steps, in this process (one worker), under
cProfile; prints the calls of each look-up function. The request is resolved once: the
system and its task once, each observer once (and the oracle for the designs' check),
a controller's design once per episode.
"""

from __future__ import annotations

import cProfile
import pstats
import tempfile

import observer_gym

LOOKUPS = ("system_for_id", "task_of", "task_for", "controllers_of", "controllers_for",
           "observer_setup", "resolve_observer", "make_env")  # fmt: skip


def main() -> None:
    with tempfile.TemporaryDirectory() as out:
        profile = cProfile.Profile()
        profile.enable()
        observer_gym.compare(
            env="BallTable-v0", observers=["kf-measurements", "oracle"], controllers=["lqr"],
            seeds=[0], steps=5, out_dir=out,
        )  # fmt: skip
        profile.disable()
    calls: dict[str, int] = {}
    for (_file, _line, name), (_cc, count, *_rest) in pstats.Stats(profile).stats.items():  # type: ignore[attr-defined]
        if name in LOOKUPS:
            calls[name] = calls.get(name, 0) + count
    print("| look-up | calls |\n|---|---|")
    for name in LOOKUPS:
        print(f"| {name} | {calls.get(name, 0)} |")


if __name__ == "__main__":
    main()
