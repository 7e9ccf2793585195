"""Env step throughput of every env on one core: rgb against the engine's floor, and
state mode against the pre-change code, each as a ratio measured in the same run.

    .venv/bin/python benchmarks/bench_envs.py --baseline-python /work/base/.venv/bin/python

What is measured, per env (BallTable-v0, BallCatcher-v1, TargetFollower-v0), with the
envs' default options:

- **steps/s** in each obs_mode: the time spent inside ``env.step`` only (resets, which
  rebuild the world, are not timed), over a fixed workload: ``--steps`` (state,
  measurements) or ``--rgb-steps`` (rgb) uniform random actions from a fixed seed,
  episode k reset with ``seed + k``. Every round runs the same workload.
- **rgb / floor**: the rgb step time over the engine's floor. The floor is the same
  engine work without our Python: a recording pass runs the rgb workload once through a
  client that logs the env's PyBullet calls per step, and the floor replays, per step,
  the calls that advance, set or image the world (``FLOOR_CALLS``: ``stepSimulation``
  x ticks_per_step, the bodies' placements, motor targets and forces, and one bare
  ``getCameraImage`` per frame captured in that step, with the recorded view and
  projection matrices) on a second instance of the same world, reset with the same
  seeds, through pre-bound ``pybullet`` functions. So BallCatcher-v1's floor renders
  the camera that captures in that step (two cameras at 50 Hz, 100 Hz steps: one frame
  per step on average), and TargetFollower-v0's (a kinematic world that never calls
  ``stepSimulation``) is its placements, the render, and its physics engine's work: the
  target's motion integrated over the step's substeps (``TargetMotion.advance``, the
  Python integrator that takes the place of ``stepSimulation`` there). Everything else in a step --
  action checks, inverse kinematics, ground-truth queries, the frame schedule, image
  copies, observation and info -- is the overhead the ratio measures (target <= 1.15).
- **state new / old**: a child process runs this file with ``--baseline-python`` (a venv
  of the pre-change code) as a worker that measures with the same function
  (:func:`timed_steps`, only ``gym.make`` / ``reset`` / ``step``), so both versions run
  the same workload on the same core, alternating new/old every round (target >= 1.0).

The machine is shared and noisy: a warm-up round is discarded, then ``--rounds`` rounds
interleave the measurements (new/old and env/floor, their order swapped every other
round); the table gives the median of the rounds' rates and the median (min-max) of the
rounds' ratios, with the load average at the start and the end. The process and its
worker are pinned to one core (``--cpu``).

Options: ``--rounds`` (default 15), ``--steps`` (800), ``--rgb-steps`` (120), ``--seed``.
Without ``--baseline-python`` the old-code columns are left empty.
"""

from __future__ import annotations

import argparse
import copy
import functools
import gc
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pybullet

import observer_gym.envs  # registers the envs

ENV_IDS = (
    "observer_gym/BallTable-v0",
    "observer_gym/BallCatcher-v1",
    "observer_gym/TargetFollower-v0",
)
# The engine calls that make up the floor: advancing, setting and imaging the world.
FLOOR_CALLS = frozenset(
    {
        "stepSimulation",
        "getCameraImage",
        "resetBasePositionAndOrientation",
        "resetBaseVelocity",
        "resetJointState",
        "setJointMotorControl2",
        "setJointMotorControlArray",
        "applyExternalForce",
    }
)
# cpu: this thread's CPU time (PyBullet's DIRECT client and TinyRenderer run in the
# calling thread), which leaves out the time other processes hold the core; wall: elapsed.
CLOCKS = {"cpu": time.thread_time, "wall": time.perf_counter}


# --- the measuring function: runs under the new and the pre-change code ---------------------
def timed_steps(env: gym.Env, steps: int, seed: int, hook=None, clock: str = "cpu") -> float:
    """Seconds spent inside ``env.step`` (by ``CLOCKS[clock]``) over ``steps`` uniform
    random actions (seeded); episode k is reset with ``seed + k``, untimed. ``hook(kind)``
    is called after every reset ("reset") and step ("step") when given (the floor's
    recording pass)."""
    rng = np.random.default_rng(seed)
    low, high = env.action_space.low, env.action_space.high
    actions = rng.uniform(low, high, size=(steps, *low.shape)).astype(low.dtype)
    episode = 0
    env.reset(seed=seed)
    if hook is not None:
        hook("reset")
    gc.collect()
    now = CLOCKS[clock]
    total = 0.0
    for action in actions:
        start = now()
        _, _, terminated, truncated, _ = env.step(action)
        total += now() - start
        if hook is not None:
            hook("step")
        if terminated or truncated:
            episode += 1
            env.reset(seed=seed + episode)
            if hook is not None:
                hook("reset")
    return total


class Meter:
    """Envs kept across rounds (built once, per env id and obs_mode)."""

    def __init__(self) -> None:
        self.envs: dict[tuple[str, str], gym.Env] = {}

    def rate(self, env_id: str, obs_mode: str, steps: int, seed: int, clock: str) -> float:
        key = (env_id, obs_mode)
        if key not in self.envs:
            self.envs[key] = gym.make(env_id, obs_mode=obs_mode)
        return steps / timed_steps(self.envs[key], steps, seed, clock=clock)

    def close(self) -> None:
        for env in self.envs.values():
            env.close()


def worker() -> None:
    """Serve ``{"env_id", "obs_mode", "steps", "seed"}`` requests (one JSON line each) with
    ``{"rate": steps/s}``; PyBullet's own prints go to stderr, not into the replies."""
    replies = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    meter = Meter()
    code = os.path.dirname(observer_gym.envs.__file__)
    replies.write(json.dumps({"code": code, "python": sys.version.split()[0]}) + "\n")
    for line in sys.stdin:
        request = json.loads(line)
        if request.get("quit"):
            break
        rate = meter.rate(
            request["env_id"],
            request["obs_mode"],
            request["steps"],
            request["seed"],
            request["clock"],
        )
        replies.write(json.dumps({"rate": rate}) + "\n")
    meter.close()


class Baseline:
    """The worker process running the pre-change code."""

    def __init__(self, python: str) -> None:
        self.log = tempfile.TemporaryFile("w+")
        self.proc = subprocess.Popen(
            [python, str(Path(__file__).resolve()), "--worker"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self.log,
            text=True,
        )
        self.hello = self._reply()

    def _reply(self) -> dict[str, Any]:
        line = self.proc.stdout.readline()
        if not line:
            self.log.seek(0)
            raise RuntimeError(f"baseline worker died:\n{self.log.read()[-3000:]}")
        return json.loads(line)

    def rate(self, env_id: str, obs_mode: str, steps: int, seed: int, clock: str) -> float:
        request = {
            "env_id": env_id,
            "obs_mode": obs_mode,
            "steps": steps,
            "seed": seed,
            "clock": clock,
        }
        self.proc.stdin.write(json.dumps(request) + "\n")
        self.proc.stdin.flush()
        return self._reply()["rate"]

    def close(self) -> None:
        self.proc.stdin.write(json.dumps({"quit": True}) + "\n")
        self.proc.stdin.flush()
        self.proc.wait(timeout=60)


# --- the floor (new code only) ---------------------------------------------------------
class _RecordingClient:
    """Forwards to a BulletClient, logging the ``FLOOR_CALLS`` (name, args, kwargs)."""

    def __init__(self, client, log: list) -> None:
        self._real = client
        self._log = log

    def __getattr__(self, name: str):
        attribute = getattr(self._real, name)
        if name not in FLOOR_CALLS:
            return attribute

        def recorded(*args, **kwargs):
            self._log.append((name, copy.deepcopy(args), copy.deepcopy(kwargs)))
            return attribute(*args, **kwargs)

        return recorded


class Floor:
    """The engine calls of the rgb workload, recorded once, replayed bare per step."""

    def __init__(self, env_id: str, steps: int, seed: int) -> None:
        self.steps, self.seed = steps, seed
        # Recording pass: episodes -> steps -> [(name, args, kwargs)].
        recorder = gym.make(env_id, obs_mode="rgb")
        sim = recorder.unwrapped.sim
        log: list = []
        real = sim.client
        sim.client = _RecordingClient(real, log)
        real_step = sim.step  # Simulation.step calls pybullet directly, not the client

        def step(substeps: int = 1) -> None:
            log.extend([("stepSimulation", (), {})] * substeps)
            real_step(substeps)

        sim.step = step
        self.episodes: list[list[list]] = []

        def hook(kind: str) -> None:
            if kind == "reset":
                self.episodes.append([])
            else:
                self.episodes[-1].append(list(log))
            log.clear()

        timed_steps(recorder, steps, seed, hook)
        sim.client = real
        del sim.step
        recorder.close()
        self.episodes = [e for e in self.episodes if e]
        counts = Counter(name for e in self.episodes for s in e for name, _, _ in s)
        self.calls_per_step = {name: n / steps for name, n in sorted(counts.items())}
        self.env = gym.make(env_id, obs_mode="rgb")  # the world the floor replays into

    def rate(self, clock: str) -> float:
        total = 0.0
        now = CLOCKS[clock]
        for k, episode in enumerate(self.episodes):
            self.env.reset(seed=self.seed + k)
            cid = self.env.unwrapped.sim.client_id
            bound = {
                n: functools.partial(getattr(pybullet, n), physicsClientId=cid) for n in FLOOR_CALLS
            }
            replay = [[(bound[n], a, kw) for n, a, kw in step] for step in episode]
            physics = self._kinematics()
            gc.collect()
            for calls in replay:
                start = now()
                physics()
                for call, args, kwargs in calls:
                    call(*args, **kwargs)
                total += now() - start
        return self.steps / total

    def _kinematics(self):
        """The per-step work of a kinematic world's own integrator (TargetFollower-v0's
        target motion over the step's substeps), or nothing for a PyBullet-stepped one."""
        base = self.env.unwrapped
        scene = getattr(base, "scene", None)
        motion = getattr(scene, "motion", None)
        if motion is None:
            return lambda: None
        twin = copy.deepcopy(motion)  # advancing it leaves the env's own motion as it was
        dt_s, substeps = base.config.dt_s, base.ticks_per_step
        return lambda: twin.advance(dt_s, substeps)

    def close(self) -> None:
        self.env.close()


# --- the run ---------------------------------------------------------------------------
def median_range(values: list[float], fmt: str) -> str:
    return f"{statistics.median(values):{fmt}} ({min(values):{fmt}}-{max(values):{fmt}})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline-python", help="python of a venv with the pre-change code")
    parser.add_argument("--rounds", type=int, default=15, help="measured rounds (after a warm-up)")
    parser.add_argument(
        "--steps", type=int, default=800, help="steps per round: state, measurements"
    )
    parser.add_argument("--rgb-steps", type=int, default=120, help="steps per round: rgb and floor")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--cpu", type=int, help="the core to pin to (default: the first allowed)")
    parser.add_argument(
        "--clock",
        choices=tuple(CLOCKS),
        default="cpu",
        help="time steps by thread CPU time or wall",
    )
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):  # one core, inherited by the worker
        os.sched_setaffinity(
            0, {args.cpu if args.cpu is not None else min(os.sched_getaffinity(0))}
        )
    if args.worker:
        worker()
        return

    load_start = os.getloadavg()
    wall_start = time.perf_counter()
    baseline = Baseline(args.baseline_python) if args.baseline_python else None
    meter = Meter()
    floors = {env_id: Floor(env_id, args.rgb_steps, args.seed) for env_id in ENV_IDS}
    results: dict[str, dict[str, list[float]]] = {
        env_id: {k: [] for k in ("new", "old", "measurements", "rgb", "floor")}
        for env_id in ENV_IDS
    }
    for r in range(args.rounds + 1):  # round 0: the warm-up (a quarter of the state steps)
        steps = args.steps if r > 0 else max(args.steps // 4, 1)
        swap = r % 2 == 1  # new/old and env/floor in the other order every other round
        for env_id in ENV_IDS:
            state_runs = [("new", meter)] + ([("old", baseline)] if baseline else [])
            rgb_runs = [
                (
                    "rgb",
                    functools.partial(
                        meter.rate, env_id, "rgb", args.rgb_steps, args.seed, args.clock
                    ),
                ),
                ("floor", functools.partial(floors[env_id].rate, args.clock)),
            ]
            row = {}
            for name, source in reversed(state_runs) if swap else state_runs:
                row[name] = source.rate(env_id, "state", steps, args.seed, args.clock)
            row["measurements"] = meter.rate(env_id, "measurements", steps, args.seed, args.clock)
            for name, run in reversed(rgb_runs) if swap else rgb_runs:
                row[name] = run()
            if r > 0:
                for name, value in row.items():
                    results[env_id][name].append(value)
    load_end = os.getloadavg()
    wall_s = time.perf_counter() - wall_start

    print(
        f"new code: {os.path.dirname(observer_gym.envs.__file__)} (python {sys.version.split()[0]})"
    )
    if baseline:
        hello = baseline.hello
        print(f"old code: {hello['code']} (python {hello['python']}, {args.baseline_python})")
    cpu = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else "?"
    print(
        f"one core {cpu}; {args.rounds} rounds after a warm-up; per round {args.steps} steps "
        f"(state, measurements) and {args.rgb_steps} steps (rgb, floor); medians over rounds, "
        f"ratios as median (min-max) of the rounds' ratios; clock: {args.clock}"
    )
    print()
    header = (
        "| env | state new steps/s | state old steps/s | state new/old | measurements steps/s "
        "| rgb steps/s | floor steps/s | rgb/floor |"
    )
    print(header)
    print("|" + "|".join("---" for _ in range(8)) + "|")
    for env_id in ENV_IDS:
        res = results[env_id]
        med = {k: statistics.median(v) if v else float("nan") for k, v in res.items()}
        if res["old"]:
            old = f"{med['old']:.0f}"
            ratio = median_range(
                [n / o for n, o in zip(res["new"], res["old"], strict=True)], ".3f"
            )
        else:
            old = ratio = "n/a"
        overhead = median_range(
            [f / g for f, g in zip(res["floor"], res["rgb"], strict=True)], ".3f"
        )
        print(
            f"| {env_id.split('/')[-1]} | {med['new']:.0f} | {old} | {ratio} "
            f"| {med['measurements']:.0f} | {med['rgb']:.1f} | {med['floor']:.1f} | {overhead} |"
        )
    print()
    print(f"rounds: {args.rounds} (+1 warm-up); wall time {wall_s:.0f} s")
    print(
        "load average (1, 5, 15 min): start "
        + ", ".join(f"{x:.2f}" for x in load_start)
        + "; end "
        + ", ".join(f"{x:.2f}" for x in load_end)
    )
    for env_id in ENV_IDS:
        calls = ", ".join(f"{n} {c:.2f}" for n, c in floors[env_id].calls_per_step.items())
        print(f"floor of {env_id.split('/')[-1]}, calls per step: {calls}")
    meter.close()
    for floor in floors.values():
        floor.close()
    if baseline:
        baseline.close()


if __name__ == "__main__":
    main()
