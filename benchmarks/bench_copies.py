"""What a copy of an env costs: pickled size and unpickle time after 1k, 10k and 50k steps,
before and after the bounded action history, and why a copy replays (PyBullet's restore).

    .venv/bin/python benchmarks/bench_copies.py --baseline-commit 7839593

A copy (``pickle``, ``copy.deepcopy``) rebuilds the world and replays the episode's
actions (envs/core.py), so its size grows with the actions kept and its unpickle time
with the steps replayed. Per env (BallTable-v0, BallCatcher-v1, TargetFollower-v0;
``obs_mode="state"``, the unwrapped env so no time limit ends the episode; zero actions
from ``reset(seed=0)``), one episode is stepped to each step count and
``pickle.dumps(env)`` is measured there: its size, and the time of one ``pickle.loads``
(the replay). Columns:

- **before**: the code at ``--baseline-commit`` (a list of every action since the reset),
  run in a worker process that imports ``observer_gym`` from that commit's tree
  (``git archive``).
- **after**: this tree with the default ``copy_history_max_steps`` (10,000): past it the
  copy is refused (``EpisodeTooLongToCopyError``).
- **after, cap 50k**: this tree with ``copy_history_max_steps = 50_000``.

The second table is why a copy replays instead of restoring a saved world: BallTable-v0
stepped 5 steps from ``reset(seed)`` with random tilts (seed 1), saved with
``saveBullet`` and restored with ``restoreState`` into a world rebuilt by the same reset;
both then get the same 10 steps, and the table gives the largest difference of any body
pose, velocity or joint state between them at the restore, one step on and over the 10
steps (0 is a bit-identical continuation). ``--restore-only`` prints this table alone. One run,
one process; the load average is printed at the start and the end.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
ENV_CLASSES = {
    "BallTable-v0": "observer_gym.envs.ball_table:BallTableEnv",
    "BallCatcher-v1": "observer_gym.envs.ball_catcher:BallCatcherEnv",
    "TargetFollower-v0": "observer_gym.envs.target_follower:TargetFollowerEnv",
}
STEP_COUNTS = (1_000, 10_000, 50_000)


def _env_class(path: str):
    import importlib

    module, name = path.split(":")
    return getattr(importlib.import_module(module), name)


def measure(cap_steps: int | None) -> dict[str, list[dict]]:
    """Per env, per step count: pickled bytes and unpickle seconds (None: refused)."""
    rows: dict[str, list[dict]] = {}
    for name, path in ENV_CLASSES.items():
        env = _env_class(path)(obs_mode="state")
        if cap_steps is not None:
            env.copy_history_max_steps = cap_steps
        env.reset(seed=0)
        action = np.zeros(env.action_space.shape, env.action_space.dtype)
        done, out = 0, []
        for steps in STEP_COUNTS:
            for _ in range(steps - done):
                env.step(action)
            done = steps
            try:
                data = pickle.dumps(env)
            except pickle.PicklingError as error:
                out.append({"steps": steps, "bytes": None, "seconds": None, "error": str(error)})
                continue
            start = time.perf_counter()
            twin = pickle.loads(data)
            seconds = time.perf_counter() - start
            twin.close()
            out.append({"steps": steps, "bytes": len(data), "seconds": seconds})
        env.close()
        rows[name] = out
    return rows


def restore_deviation(seeds=range(5)) -> list[tuple[int, float, float, float]]:
    """Per reset seed: the largest difference between a BallTable world and a rebuilt one
    restored from its ``saveBullet`` file, right after the restore, after one step and
    over the 10 steps after it."""
    from observer_gym.envs.ball_table import BallTableEnv

    def flat(sim) -> np.ndarray:
        client, values = sim.client, []
        for index in range(client.getNumBodies()):
            body = client.getBodyUniqueId(index)
            pos, quat = client.getBasePositionAndOrientation(body)
            lin, ang = client.getBaseVelocity(body)
            values += [*pos, *quat, *lin, *ang]
            for joint in range(client.getNumJoints(body)):
                values += client.getJointState(body, joint)[:2]
        return np.array(values)

    tilts = np.random.default_rng(1).uniform(-0.1, 0.1, (15, 2))
    out = []
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, "world.bullet")
        for seed in seeds:
            original = BallTableEnv(obs_mode="state")
            original.reset(seed=seed)
            for tilt in tilts[:5]:
                original.scene.command_tilt(*tilt.tolist())
                original.sim.step(original.ticks_per_step)
            original.sim.client.saveBullet(path)
            restored = BallTableEnv(obs_mode="state")
            restored.reset(seed=seed)
            restored.sim.client.restoreState(fileName=path)
            at_restore = float(np.max(np.abs(flat(original.sim) - flat(restored.sim))))
            deviations = []
            for tilt in tilts[5:]:
                for env in (original, restored):
                    env.scene.command_tilt(*tilt.tolist())
                    env.sim.step(env.ticks_per_step)
                deviations.append(float(np.max(np.abs(flat(original.sim) - flat(restored.sim)))))
            out.append((seed, at_restore, deviations[0], max(deviations)))
            original.close()
            restored.close()
    return out


def baseline(commit: str) -> dict[str, list[dict]]:
    """:func:`measure` run by the code at ``commit``, in a worker process."""
    with tempfile.TemporaryDirectory(prefix="bench_copies_base_") as folder:
        archive = os.path.join(folder, "base.tar")
        subprocess.run(
            ["git", "-C", str(REPO), "archive", "-o", archive, commit, "observer_gym", "envs"],
            check=True,
        )
        tree = os.path.join(folder, "tree")
        with tarfile.open(archive) as tar:
            tar.extractall(tree, filter="data")
        # observer_gym.envs lives in envs/ in the source tree (pyproject's package-dir).
        os.symlink(os.path.join(tree, "envs"), os.path.join(tree, "observer_gym", "envs"))
        env = {**os.environ, "PYTHONPATH": tree}
        result = subprocess.run(
            [sys.executable, __file__, "--worker"],
            check=True,
            capture_output=True,
            text=True,
            env=env,
        )
    answer = json.loads(result.stdout.strip().splitlines()[-1])
    if not answer["module"].startswith(tree):
        raise RuntimeError(f"the worker imported {answer['module']}, not the baseline tree")
    return answer["rows"]


def _cell(row: dict | None) -> str:
    if row is None:
        return "-"
    if row["bytes"] is None:
        return "refused"
    return f"{row['bytes'] / 1024:9.1f} KB {row['seconds']:7.3f} s"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline-commit", help="the code before the change (git rev)")
    parser.add_argument(
        "--restore-only", action="store_true", help="only the second table (PyBullet's restore)"
    )
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        import observer_gym.envs

        rows = measure(None)
        print(json.dumps({"module": observer_gym.envs.__file__, "rows": rows}))
        return

    load_start = os.getloadavg()
    if args.restore_only:
        deviations = restore_deviation()
        print(f"load average (1, 5, 15 min): start {load_start}, end {os.getloadavg()}")
        _print_restore(deviations)
        return
    before = baseline(args.baseline_commit) if args.baseline_commit else None
    after = measure(None)
    after_50k = measure(50_000)
    deviations = restore_deviation()
    load_end = os.getloadavg()

    print(f"load average (1, 5, 15 min): start {load_start}, end {load_end}")
    print(f"cpu count {os.cpu_count()}; obs_mode=state; pickled size, one pickle.loads")
    print()
    header = f"{'env':18} {'steps':>6} | {'before':>22} | {'after':>22} | {'after, cap 50k':>22}"
    print(header)
    print("-" * len(header))
    for name in ENV_CLASSES:
        for i, steps in enumerate(STEP_COUNTS):
            old = before[name][i] if before else None
            print(
                f"{name:18} {steps:>6} | {_cell(old):>22} | {_cell(after[name][i]):>22} | "
                f"{_cell(after_50k[name][i]):>22}"
            )
    print()
    print("bytes per step (10k -> 50k, cap 50k):", end="")
    for name in ENV_CLASSES:
        small, large = after_50k[name][1], after_50k[name][2]
        per_step = (large["bytes"] - small["bytes"]) / (large["steps"] - small["steps"])
        text = f" {name} {per_step:.1f} B"
        if before:
            old_small, old_large = before[name][1], before[name][2]
            old_per_step = (old_large["bytes"] - old_small["bytes"]) / (
                old_large["steps"] - old_small["steps"]
            )
            text += f" (before {old_per_step:.1f} B)"
        print(text, end=";")
    print()
    print()
    _print_restore(deviations)


def _print_restore(deviations) -> None:
    print("BallTable-v0, saveBullet -> restoreState into a rebuilt world; largest difference")
    print("of any body pose, velocity or joint state from the original:")
    print(f"{'reset seed':>10} | {'at the restore':>14} | {'1 step on':>10} | {'10 steps on':>11}")
    for seed, at_restore, one, ten in deviations:
        print(f"{seed:>10} | {at_restore:14.3e} | {one:10.3e} | {ten:11.3e}")


if __name__ == "__main__":
    main()
