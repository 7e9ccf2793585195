"""``observer-gym demo``: a short BallTable-v0 run that writes frames, a plot and a summary.

There is no controller yet, so the demo drives the table with a SCRIPTED, open-loop tilt
that should roll the ball around a circle. Being open loop, the ball drifts off the
circle; the plot shows how far, honestly.
"""

from __future__ import annotations

import json
import os
import tempfile
import time
from datetime import datetime
from importlib import metadata
from pathlib import Path
from typing import Any

import cv2
import gymnasium as gym
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from tqdm import tqdm

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.envs.ball_table import BallTableConfig
from observer_gym.envs.ball_table.geometry import BALL_TRAVEL_M, TABLE_SIDE_M
from observer_gym.envs.ball_table.layout import BALL_POS, TILT
from observer_gym.envs.sim import GRAVITY_MPS2

ENV_ID = "observer_gym/BallTable-v0"
ROLLING_GAIN = 5.0 / 7.0  # a = (5/7) g sin(tilt) for a solid ball rolling without slipping
CIRCLE_RADIUS_M = 0.06  # rho
CIRCLE_RATE_RADPS = 1.5  # w
ARM_LAG_S = 0.04  # the arm's first-order tilt lag; the command is evaluated this far ahead
VERSIONED_PACKAGES = ("observer-gym", "gymnasium", "pybullet", "numpy")


def circle_tilt_rad(time_s: float) -> np.ndarray:
    """The tilt command (tilt_x, tilt_y) that rolls the ball around the demo circle.

    The path p(t) = rho (cos wt, sin wt) needs the acceleration a = -rho w^2 (cos wt, sin wt).
    Inverting a_x = (5/7) g tilt_y and a_y = -(5/7) g tilt_x (small angles) gives the tilt.
    The caller passes a time ``ARM_LAG_S`` ahead to make up for the arm's lag.
    """
    accel_scale_mps2 = CIRCLE_RADIUS_M * CIRCLE_RATE_RADPS**2
    phase_rad = CIRCLE_RATE_RADPS * time_s
    accel_x_mps2 = -accel_scale_mps2 * np.cos(phase_rad)
    accel_y_mps2 = -accel_scale_mps2 * np.sin(phase_rad)
    gain_mps2 = ROLLING_GAIN * GRAVITY_MPS2
    return np.array([-accel_y_mps2 / gain_mps2, accel_x_mps2 / gain_mps2])


def default_out_dir() -> Path:
    """``observer-gym-out/demo-YYYYmmdd-HHMMSS`` under the current directory."""
    return Path.cwd() / "observer-gym-out" / f"demo-{datetime.now():%Y%m%d-%H%M%S}"


def package_versions() -> dict[str, str]:
    """Installed versions of the packages that decide what the demo computes."""
    versions = {}
    for name in VERSIONED_PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = "not installed"
    return versions


def run_demo(
    out_dir: Path | None = None,
    seconds: float = 10.0,
    seed: int = 0,
    frame_every: int = 50,
    progress: bool = True,
) -> dict[str, Any]:
    """Run BallTable-v0 (rgb observations, default config) under a scripted tilt.

    No controller exists yet: the tilt is SCRIPTED and open loop (see
    :func:`circle_tilt_rad`), aiming the ball around a circle of radius 0.06 m at
    1.5 rad/s from the reset state ball_pos_table_m = (rho, 0), ball_vel_table_mps =
    (0, rho w). The ball drifts; nothing corrects it. An episode that terminates (ball
    over a border) stops early and is recorded as such.

    Writes into ``out_dir`` (default :func:`default_out_dir`; created if missing):
    ``frames/frame_XXXX.png`` (the camera frame every ``frame_every`` steps, XXXX the step),
    ``trajectory.png`` (ball path in the table frame; distance and tilt vs time) and
    ``summary.json`` (written atomically). Prints a note, shows a tqdm progress bar when
    ``progress`` is set, and prints the output folder at the end.

    Args:
        out_dir: the output folder.
        seconds: simulated duration; rounded to whole env steps (50 per second).
        seed: the env's reset seed.
        frame_every: save every this many steps' frame (step 0 included).
        progress: show the progress bar.

    Returns:
        The summary written to ``summary.json``; ``trajectory`` holds the recorded ground
        truth (``info["state"]``) after reset and after every step.

    Raises:
        ValueError: ``seconds`` is not positive and finite, or ``frame_every`` < 1.
    """
    if not (np.isfinite(seconds) and seconds > 0):
        raise ValueError(f"seconds must be a positive, finite number, got {seconds!r}")
    if frame_every < 1:
        raise ValueError(f"frame_every must be >= 1, got {frame_every!r}")
    out_dir = Path(out_dir) if out_dir is not None else default_out_dir()
    frames_dir = out_dir / "frames"
    frames_dir.mkdir(parents=True, exist_ok=True)

    print(
        "observer-gym demo: no controller yet, so the table follows a SCRIPTED open-loop "
        f"tilt meant to roll the ball around a {CIRCLE_RADIUS_M} m circle; expect drift."
    )
    dt_s = BallTableConfig().dt_s
    steps_wanted = max(1, round(seconds / dt_s))
    # Our own time limit: the registered one (10 s) would cut longer demos short.
    env = gym.make(ENV_ID, obs_mode="rgb", max_episode_steps=steps_wanted)
    try:
        record = _run_episode(env, dt_s, steps_wanted, seed, frame_every, frames_dir, progress)
    finally:
        env.close()

    files = [p.relative_to(out_dir).as_posix() for p in record["frame_paths"]]
    _plot_trajectory(record, out_dir / "trajectory.png")
    files += ["trajectory.png", "summary.json"]

    ball_pos_m = np.array(record["ball_pos_table_m"])
    distance_m = np.linalg.norm(ball_pos_m, axis=1)
    summary = {
        "env_id": ENV_ID,
        "seed": seed,
        "seconds": seconds,
        "dt_s": dt_s,
        "steps": record["steps"],
        "controller": "scripted open-loop circle (no feedback)",
        "mean_ball_distance_m": float(np.mean(distance_m)),
        "final_ball_distance_m": float(distance_m[-1]),
        "max_abs_tilt_rad": float(np.max(np.abs(record["tilt_rad"]))),
        "max_abs_tilt_cmd_rad": float(np.max(np.abs(record["tilt_cmd_rad"]))),
        "terminated": record["terminated"],
        "mean_step_time_s": record["mean_step_time_s"],
        "versions": package_versions(),
        "files": files,
        "trajectory": {
            "time_s": record["time_s"],
            "ball_pos_table_m": record["ball_pos_table_m"],
            "tilt_rad": record["tilt_rad"],
        },
    }
    _write_json_atomic(summary, out_dir / "summary.json")
    print(
        f"steps {summary['steps']}, mean ball distance {summary['mean_ball_distance_m']:.4f} m,"
        f" final {summary['final_ball_distance_m']:.4f} m, terminated {summary['terminated']}"
    )
    print(f"output: {out_dir}")
    return summary


def _run_episode(
    env: gym.Env,
    dt_s: float,
    steps_wanted: int,
    seed: int,
    frame_every: int,
    frames_dir: Path,
    progress: bool,
) -> dict[str, Any]:
    """Reset, step under the scripted tilt, save frames; the recorded ground truth."""
    start_pos_m = (CIRCLE_RADIUS_M, 0.0)
    start_vel_mps = (0.0, CIRCLE_RADIUS_M * CIRCLE_RATE_RADPS)
    obs, info = env.reset(
        seed=seed, options={"ball_pos_table_m": start_pos_m, "ball_vel_table_mps": start_vel_mps}
    )
    record: dict[str, Any] = {"time_s": [], "ball_pos_table_m": [], "tilt_rad": []}
    record["tilt_cmd_rad"] = []
    record["frame_paths"] = []

    def remember(info: dict) -> None:
        state = info["state"]
        record["time_s"].append(round(float(info["time_s"]), 9))
        record["ball_pos_table_m"].append([float(v) for v in state[BALL_POS]])
        record["tilt_rad"].append([float(v) for v in state[TILT]])

    remember(info)
    record["frame_paths"].append(_save_frame(obs, frames_dir, 0))
    terminated = truncated = False
    step_time_s = 0.0
    steps = 0
    with tqdm(total=steps_wanted, unit="step", desc="demo", disable=not progress) as bar:
        while steps < steps_wanted and not (terminated or truncated):
            tilt_cmd_rad = circle_tilt_rad(steps * dt_s + ARM_LAG_S)
            tic_s = time.perf_counter()
            obs, _, terminated, truncated, info = env.step(tilt_cmd_rad.astype(np.float32))
            step_time_s += time.perf_counter() - tic_s
            steps += 1
            record["tilt_cmd_rad"].append([float(v) for v in tilt_cmd_rad])
            remember(info)
            if steps % frame_every == 0:
                record["frame_paths"].append(_save_frame(obs, frames_dir, steps))
            bar.update(1)
    record.update(
        steps=steps, terminated=bool(terminated), mean_step_time_s=step_time_s / max(steps, 1)
    )
    return record


def _save_frame(rgb: np.ndarray, frames_dir: Path, step: int) -> Path:
    """Write an RGB frame as ``frames_dir/frame_XXXX.png`` (XXXX the step); its path."""
    path = frames_dir / f"frame_{step:04d}.png"
    if not cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)):
        raise OSError(f"could not write {path}")
    return path


def _plot_trajectory(record: dict[str, Any], path: Path) -> None:
    """Left: ball path in the table frame. Right: distance from centre and tilt vs time."""
    time_s = np.array(record["time_s"])
    ball_pos_m = np.array(record["ball_pos_table_m"])
    tilt_rad = np.array(record["tilt_rad"])
    distance_m = np.linalg.norm(ball_pos_m, axis=1)

    fig = Figure(figsize=(11, 4.8), layout="constrained")
    FigureCanvasAgg(fig)
    path_ax, time_ax = fig.subplots(1, 2, width_ratios=(1, 1.4))

    def square(ax, half_m: float, **style) -> None:
        xs = half_m * np.array([1, -1, -1, 1, 1])
        ys = half_m * np.array([1, 1, -1, -1, 1])
        ax.plot(xs, ys, **style)

    square(path_ax, TABLE_SIDE_M / 2, color="k", lw=1.5, label="table edge (±0.15 m)")
    square(path_ax, BALL_TRAVEL_M, color="0.5", ls="--", lw=1, label="reachable (±0.125 m)")
    phase_rad = np.linspace(0, 2 * np.pi, 200)
    path_ax.plot(
        CIRCLE_RADIUS_M * np.cos(phase_rad),
        CIRCLE_RADIUS_M * np.sin(phase_rad),
        color="tab:green",
        ls=":",
        label="scripted circle",
    )
    path_ax.plot(ball_pos_m[:, 0], ball_pos_m[:, 1], color="tab:blue", lw=1.2, label="ball")
    path_ax.plot(*ball_pos_m[0], "o", color="tab:blue", label="start")
    path_ax.plot(*ball_pos_m[-1], "x", color="tab:red", label="end")
    path_ax.set(xlabel="x table (m)", ylabel="y table (m)", title="Ball path, table frame")
    path_ax.set_aspect("equal")
    path_ax.legend(loc="upper right", fontsize=7)

    time_ax.plot(time_s, distance_m, color="tab:blue", label="ball distance from centre")
    time_ax.axhline(CIRCLE_RADIUS_M, color="tab:green", ls=":", label="circle radius")
    time_ax.set(xlabel="time (s)", ylabel="distance (m)", title="Scripted open-loop tilt")
    tilt_ax = time_ax.twinx()
    tilt_ax.plot(time_s, tilt_rad[:, 0], color="tab:orange", lw=1, label="tilt_x")
    tilt_ax.plot(time_s, tilt_rad[:, 1], color="tab:purple", lw=1, label="tilt_y")
    tilt_ax.set_ylabel("tilt (rad)")
    lines = time_ax.get_lines() + tilt_ax.get_lines()
    time_ax.legend(lines, [line.get_label() for line in lines], loc="upper left", fontsize=7)
    fig.savefig(path, dpi=110)


def _write_json_atomic(data: dict[str, Any], path: Path) -> None:
    """Write JSON to a temp file beside ``path``, then rename it into place."""
    fd, tmp_name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            json.dump(data, f, indent=2)
            f.write("\n")
        os.chmod(tmp_name, 0o644)  # mkstemp makes it owner-only
        os.replace(tmp_name, path)
    except BaseException:
        Path(tmp_name).unlink(missing_ok=True)
        raise
