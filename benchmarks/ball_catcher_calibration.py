"""What the cameras' calibration error costs BallCatcher, and what the self-calibrating
observers win back (docs/results/ball_catcher_calibration.md).

Three tables and a figure, on throws the suite never uses (seeds 5000 on; the suite's
are 2 000 000 on), perfect-detector measurements, the intercept controller:

1. Catch rate per observer at the suite's ``lab`` and ``field`` levels, beside bounds
   that read the truth (analysis only, no observer of the package does this): the pixel
   EKF fed each frame's true camera (``info["truth"]["frames"]``), for both cameras or
   one, and at four cameras, with the faster arm and at 100 frames/s.
2. The ablation: estimated calibration alone (``selfcal``), the hole as a landmark with
   the calibration only considered (``endpoint``, ``estimated=()``), both (``endpoint``);
   at lab, at lab without its calibration errors, and each of lab's calibration options
   alone (on the ideal level's defaults, as docs/benchmark.md's ablation).
3. One rig over consecutive throws (``calib_error_draw="fixed"``): each camera's image
   error through the estimated camera against the true one, per throw, and the catch
   rate with the estimate carried over and without; drawn to ``--figure``.

    python benchmarks/ball_catcher_calibration.py --throws 200 --workers 2 \\
        --figure docs/results/img/ball_catcher_calibration_fixed.png
"""

from __future__ import annotations

import argparse
import json
import math
import time
from concurrent.futures import ProcessPoolExecutor
from importlib import resources
from typing import Any

import gymnasium as gym
import numpy as np

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.controllers import make_controller
from observer_gym.envs.camera import project_points
from observer_gym.estimation.ball_catcher import (
    BallCatcherObserver,
    EndpointObserver,
    PixelEKFObserver,
    SelfCalibratingObserver,
)
from observer_gym.estimation.calibration import moved_camera

ENV_ID = "observer_gym/BallCatcher-v1"
SEED = 5000
FIXED_SEED = 7000


def suite_levels() -> dict[str, dict[str, Any]]:
    suite = resources.files("observer_gym.train.experiments.benchmark.suites.v1")
    text = suite.joinpath("ball_catcher.json").read_text()
    return {name: level["env_options"] for name, level in json.loads(text)["levels"].items()}


class TrueCameras:
    """Analysis only: the pixel EKF fed each frame's true camera (``cameras``: which)."""

    def __init__(self, env, cameras: tuple[int, ...]) -> None:
        self.inner = PixelEKFObserver(env)
        self.cameras = cameras

    def reset(self) -> None:
        self.inner.reset()

    def observe(self, obs, info, action):
        frames = [
            dict(f, K=t["K"], T_world_cam=t["T_world_cam"]) if f["camera_id"] in self.cameras else f
            for f, t in zip(info["frames"], info["truth"]["frames"], strict=True)
        ]
        return self.inner.observe(obs, {**info, "frames": frames}, action)


def make_observer(name: str, env):
    base = env.unwrapped
    if name == "kf":
        return BallCatcherObserver(base)
    if name == "ekf":
        return PixelEKFObserver(base)
    if name == "selfcal":
        return SelfCalibratingObserver(base)
    if name == "endpoint":
        return EndpointObserver(base)
    if name == "endpoint, calibration considered":
        return EndpointObserver(base, estimated=())
    if name == "endpoint, nothing carried":
        return EndpointObserver(base, carry_over=False)
    if name.startswith("ekf, true camera"):
        cameras = tuple(range(base.num_cameras)) if name.endswith("s") else (int(name[-1]),)
        return TrueCameras(base, cameras)
    raise ValueError(f"unknown variant {name!r}")


def throw(env, pipeline, controller, seed: int, each_step=None) -> dict:
    """One throw from ``seed``: the intercept planner on ``pipeline``'s estimate (its
    covariance too); ``each_step(info)`` sees every step's info; the last info."""
    obs, info = env.reset(seed=seed)
    pipeline.reset()
    controller.reset()
    action = None
    while True:
        if each_step is not None:
            each_step(info)
        estimate = pipeline.observe(obs, info, action)
        controller.observe_info({"estimate": estimate.as_info()})
        command, _ = controller.predict(estimate.mean.astype(np.float32), deterministic=True)
        obs, _, terminated, truncated, info = env.step(command)
        action = info["applied_action"]
        if terminated or truncated:
            return info


def catch_rate(job: tuple[str, str, dict, int, int]) -> tuple[str, str, int, int, float]:
    """(row, observer, catches, throws, seconds) of ``throws`` throws from ``seed``."""
    row, observer, options, throws, seed = job
    start = time.perf_counter()
    env = gym.make(ENV_ID, obs_mode="measurements", hole_measurements=True, **options)
    pipeline = make_observer(observer, env)
    controller = make_controller("intercept", env)
    caught = sum(
        bool(throw(env, pipeline, controller, s)["caught"]) for s in range(seed, seed + throws)
    )
    env.close()
    return row, observer, caught, throws, time.perf_counter() - start


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """The 95 % Wilson score interval of k successes in n."""
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return centre - half, centre + half


def print_table(title: str, results: list, rows: list[str], observers: list[str]) -> None:
    cells = {(r, o): (k, n) for r, o, k, n, _ in results}
    print(f"\n{title}\n")
    print("| | " + " | ".join(observers) + " |")
    print("|---" * (len(observers) + 1) + "|")
    for row in rows:
        out = []
        for o in observers:
            if (row, o) not in cells:
                out.append("")
                continue
            k, n = cells[(row, o)]
            low, high = wilson(k, n)
            out.append(f"{k / n:.2f} [{low:.2f}, {high:.2f}]")
        print(f"| {row} | " + " | ".join(out) + " |")


def fixed_rig(throws: int, level: dict) -> dict[str, list[float]]:
    """``endpoint`` over ``throws`` consecutive throws of one rig: per throw, each
    camera's image error (px) through its estimated camera against the true one, at the
    hole's home for camera 1 and along the mean throw's path in camera 0's view."""
    env = gym.make(
        ENV_ID,
        obs_mode="measurements",
        hole_measurements=True,
        **{**level, "calib_error_draw": "fixed"},
    )
    observer = EndpointObserver(env.unwrapped)
    controller = make_controller("intercept", env)
    calibration = observer.parameters
    path = np.linspace([3.2, 0.0, 0.55], [0.7, 0.0, 0.5], 25)
    path[:, 2] += 0.5 * 9.81 * 0.22**2 * (1 - np.linspace(-1, 1, 25) ** 2)  # the arc
    points = {0: path, 1: np.array([[0.7, 0.0, 0.5]])}
    out: dict[str, list[float]] = {"camera 0": [], "camera 1": [], "nominal 0": [], "nominal 1": []}
    frames: dict[int, tuple[dict, dict]] = {}  # each camera's newest (nominal, true) frame

    def keep_frames(info: dict) -> None:
        for frame, true in zip(info["frames"], info["truth"]["frames"], strict=True):
            frames[frame["camera_id"]] = (frame, true)

    for seed in range(FIXED_SEED, FIXED_SEED + throws):
        frames.clear()
        throw(env, observer, controller, seed, keep_frames)
        x_aug = observer.estimate_in_flight()
        for camera, (frame, true) in sorted(frames.items()):
            c = calibration.offsets(x_aug)[camera]
            K, T = moved_camera(frame["K"], frame["T_world_cam"], calibration.variances, c)
            uv_true, depth = project_points(true["K"], true["T_world_cam"], points[camera])
            w, h = frame["image_size_px"]
            seen = (depth > 0) & (uv_true[:, 0] >= 0) & (uv_true[:, 0] < w)
            seen &= (uv_true[:, 1] >= 0) & (uv_true[:, 1] < h)
            uv_est, _ = project_points(K, T, points[camera][seen])
            uv_nom, _ = project_points(frame["K"], frame["T_world_cam"], points[camera][seen])
            out[f"camera {camera}"].append(
                float(np.linalg.norm(uv_est - uv_true[seen], axis=1).mean())
            )
            out[f"nominal {camera}"].append(
                float(np.linalg.norm(uv_nom - uv_true[seen], axis=1).mean())
            )
    env.close()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--throws", type=int, default=200)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--fixed-throws", type=int, default=20)
    parser.add_argument("--figure", default=None, help="where to draw the fixed rig's errors")
    parser.add_argument(
        "--only",
        choices=("rig", "arm-and-rate"),
        default=None,
        help="only table 3 and the figure (one rig), or only table 1's arm and frame-rate rows",
    )
    args = parser.parse_args()
    levels = suite_levels()
    lab = levels["lab"]
    n = args.throws
    jobs: list[tuple[str, str, dict, int, int]] = []
    bounds = [
        "kf",
        "ekf",
        "selfcal",
        "endpoint",
        "ekf, true camera 0",
        "ekf, true camera 1",
        "ekf, true cameras",
    ]
    for level in ("lab", "field"):
        jobs += [(level, o, levels[level], n, SEED) for o in bounds]
        jobs += [
            (f"{level}, 4 cameras", o, {**levels[level], "num_cameras": 4}, n, SEED)
            for o in ("ekf", "endpoint", "ekf, true cameras")
        ]
    arm_and_rate = {
        "lab, fast arm": {"robot_profile": "fast"},
        "lab, 100 Hz": {"frame_rate_hz": 100},
    }
    for row, extra in arm_and_rate.items():
        jobs += [(row, o, {**lab, **extra}, n, SEED) for o in ("ekf", "ekf, true cameras")]
    ablation = ["ekf", "selfcal", "endpoint, calibration considered", "endpoint"]
    calibration_options = [k for k in lab if k.startswith("calib_")]
    for option in calibration_options:  # the option alone on the ideal level's defaults
        jobs += [(f"{option} alone", o, {option: lab[option]}, n, SEED) for o in ablation]
    no_calibration = {k: v for k, v in lab.items() if not k.startswith("calib_")}
    jobs += [("lab without its calibration errors", o, no_calibration, n, SEED) for o in ablation]
    jobs += [("lab", o, lab, n, SEED) for o in ablation if o not in bounds]
    fixed = {**lab, "calib_error_draw": "fixed"}
    carried = ["endpoint", "endpoint, nothing carried", "ekf"]
    jobs += [("lab, one rig (fixed)", o, fixed, n, FIXED_SEED) for o in carried]
    if args.only == "rig":
        jobs = [job for job in jobs if job[0] == "lab, one rig (fixed)"]
    elif args.only == "arm-and-rate":
        jobs = [job for job in jobs if job[0] in arm_and_rate]
    start = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as pool:
        results = list(pool.map(catch_rate, jobs))
    wall = time.perf_counter() - start
    cpu = sum(r[4] for r in results)
    print(f"{len(jobs)} cells of {n} throws, {wall:.0f} s of wall time, {cpu:.0f} s in the workers")
    if args.only != "rig":
        rows = ["lab", "lab, 4 cameras", *arm_and_rate, "field", "field, 4 cameras"]
        title = "Catch rate [95 % Wilson interval], and bounds that read the truth"
        print_table(title, results, rows, bounds)
    if args.only is None:
        rows = ["lab", "lab without its calibration errors"]
        rows += [f"{o} alone" for o in calibration_options]
        print_table("Ablation at lab", results, rows, ablation)
    if args.only == "arm-and-rate":
        return
    print_table("One rig over the throws", results, ["lab, one rig (fixed)"], carried)
    errors = fixed_rig(args.fixed_throws, lab)
    print("\nOne rig, consecutive throws: image error (px) through the estimated camera")
    print("| throw | camera 0 (nominal) | camera 0 | camera 1 (nominal) | camera 1 |")
    print("|---|---|---|---|---|")
    for i in range(args.fixed_throws):
        print(
            f"| {i + 1} | {errors['nominal 0'][i]:.2f} | {errors['camera 0'][i]:.2f} | "
            f"{errors['nominal 1'][i]:.2f} | {errors['camera 1'][i]:.2f} |"
        )
    if args.figure:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        throws = np.arange(1, args.fixed_throws + 1)
        fig, ax = plt.subplots(figsize=(8.0, 3.6))
        for camera, colour in ((0, "tab:blue"), (1, "tab:orange")):
            where = "along the flight in its view" if camera == 0 else "at the hole"
            ax.plot(
                throws,
                errors[f"camera {camera}"],
                "o-",
                color=colour,
                label=f"camera {camera}, estimated ({where})",
            )
            ax.plot(
                throws,
                errors[f"nominal {camera}"],
                "--",
                color=colour,
                label=f"camera {camera}, nominal",
            )
        ax.set_xlabel("throw (one rig, calib_error_draw='fixed', lab's errors)")
        ax.set_ylabel("image error against the true camera (px)")
        ax.set_ylim(bottom=0)
        ax.set_xticks(throws[::2] if len(throws) > 10 else throws)
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
        fig.tight_layout()
        fig.savefig(args.figure, dpi=120)
        print(f"figure: {args.figure}")


if __name__ == "__main__":
    main()
