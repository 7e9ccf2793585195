"""``observer-gym demo``: BallTable-v0 controlled through its camera.

The camera's frames go through the pixel observer (``VisionObserver``: detector + Kalman
filters) and the LQR acts on its estimate, from a start 0.1 m from the table's centre.
Writes camera frames, a plot (the ball's path, its distance from the centre, estimate
against truth with the filter's 2-sigma band) and ``summary.json``.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import cv2
import gymnasium as gym
import numpy as np

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.controllers import make_controller
from observer_gym.envs.ball_table import BallTableConfig
from observer_gym.envs.ball_table.layout import BALL_POS, BALL_VEL, TILT
from observer_gym.estimation import VisionObserver
from observer_gym.train.core.metrics import TOLERANCE_M, rmse, settling_time_s, time_within_s
from observer_gym.train.core.plots import draw_table, new_figure, save_figure
from observer_gym.train.reports.outputs import (
    check_folder_kind,
    default_out_dir,
    output_folder,
    package_versions,
    write_json_atomic,
)
from observer_gym.train.reports.progress import progress_bar

ENV_ID = "observer_gym/BallTable-v0"
CONTROLLER = "lqr"
START_DISTANCE_M = 0.1
START_DIRECTION_RAD = np.deg2rad(135.0)  # towards the camera's left, away from it
# what ``observer-gym demo`` prints before the episode
INTRODUCTION = (
    f"observer-gym demo: {ENV_ID} from camera frames; pixel observer + "
    f"{CONTROLLER.upper()}, ball starting {START_DISTANCE_M} m from the centre"
)


def run_demo(
    out_dir: Path | None = None,
    seconds: float = 10.0,
    seed: int = 0,
    frame_every: int = 50,
    progress: bool = True,
) -> dict[str, Any]:
    """Run BallTable-v0 from camera frames with the pixel observer and the LQR.

    The ball starts at rest ``START_DISTANCE_M`` from the centre (``START_DIRECTION_RAD``);
    the camera's frames (obs_mode="rgb") go through ``VisionObserver`` and the LQR of
    ``make_controller("lqr", env)`` acts on the estimate. An episode that terminates (ball
    over a border) stops early and is recorded as such.

    Writes into ``out_dir`` (default ``observer-gym-out/demo-<time>``; created if missing,
    and removed again if the demo fails before writing anything:
    :func:`~observer_gym.train.reports.outputs.output_folder`):
    ``frames/frame_XXXX.png`` (the camera frame every ``frame_every`` steps, XXXX the step),
    ``trajectory.png`` (ball path, distance from the centre, estimate vs truth) and
    ``summary.json`` (written atomically). Shows a tqdm progress bar when ``progress`` is
    set; ``observer-gym demo`` prints :data:`INTRODUCTION` and :func:`summary_text`.

    Args:
        out_dir: the output folder.
        seconds: simulated duration; rounded to whole env steps (50 per second).
        seed: the env's reset seed.
        frame_every: save every this many steps' frame (step 0 included).
        progress: show the progress bar.

    Returns:
        The summary written to ``summary.json``; ``trajectory`` holds the ground truth
        (``info["state"]``), the estimate and its standard deviation after reset and after
        every step.

    Raises:
        ValueError: ``seconds`` is not positive and finite, or ``frame_every`` < 1;
            :class:`~observer_gym.train.reports.outputs.OutputFolderError` if ``out_dir``
            holds another command's results (a training run's, a sweep's).
    """
    if not (np.isfinite(seconds) and seconds > 0):
        raise ValueError(f"seconds must be a positive, finite number, got {seconds!r}")
    if frame_every < 1:
        raise ValueError(f"frame_every must be >= 1, got {frame_every!r}")
    out_dir = Path(out_dir) if out_dir is not None else default_out_dir("demo")
    with output_folder(out_dir, "demo", check=lambda folder: check_folder_kind(folder, "demo")):
        frames_dir = out_dir / "frames"
        frames_dir.mkdir(parents=True, exist_ok=True)

        dt_s = BallTableConfig().dt_s
        steps_wanted = max(1, round(seconds / dt_s))
        # Our own time limit: the registered one (10 s) would cut longer demos short.
        env = VisionObserver(
            gym.make(
                ENV_ID, obs_mode="rgb", render_mode="rgb_array", max_episode_steps=steps_wanted
            )
        )
        try:
            controller = make_controller(CONTROLLER, env)
            record = _run_episode(
                env, controller, steps_wanted, seed, frame_every, frames_dir, progress
            )
        finally:
            env.close()

        files = [p.relative_to(out_dir).as_posix() for p in record["frame_paths"]]
        _plot_trajectory(record, out_dir / "trajectory.png")
        files += ["trajectory.png", "summary.json"]

        time_s = np.array(record["time_s"])
        truth = np.array(record["state"])
        estimate = np.array(record["estimate"])
        distance_m = np.linalg.norm(truth[:, BALL_POS], axis=1)
        summary = {
            "env_id": ENV_ID,
            "observer": "kf (VisionObserver on rgb frames)",
            "controller": CONTROLLER,
            "seed": seed,
            "seconds": seconds,
            "dt_s": dt_s,
            "steps": record["steps"],
            "start_ball_pos_table_m": record["start_ball_pos_table_m"],
            "mean_ball_distance_m": float(np.mean(distance_m)),
            "final_ball_distance_m": float(distance_m[-1]),
            "settling_time_s": settling_time_s(time_s, distance_m),
            "time_within_1cm_s": time_within_s(time_s, distance_m),
            "ball_pos_rmse_m": rmse(estimate[:, BALL_POS], truth[:, BALL_POS]),
            "ball_vel_rmse_mps": rmse(estimate[:, BALL_VEL], truth[:, BALL_VEL]),
            "max_abs_tilt_cmd_rad": float(np.max(np.abs(record["tilt_cmd_rad"]))),
            "terminated": record["terminated"],
            "mean_step_time_s": record["mean_step_time_s"],
            "versions": package_versions(),
            "files": files,
            "trajectory": {
                "time_s": record["time_s"],
                "state": record["state"],
                "estimate": record["estimate"],
                "estimate_std": record["estimate_std"],
            },
        }
        write_json_atomic(out_dir / "summary.json", summary)
        return summary


def summary_text(summary: dict[str, Any]) -> str:
    """What ``observer-gym demo`` prints of :func:`run_demo`'s summary."""
    settled = summary["settling_time_s"]
    return (
        f"steps {summary['steps']}: within {TOLERANCE_M * 100:.0f} cm of the centre from "
        + (f"{settled:.2f} s on" if settled is not None else "never (not settled)")
        + f"; mean distance {summary['mean_ball_distance_m'] * 1000:.1f} mm, final "
        f"{summary['final_ball_distance_m'] * 1000:.2f} mm; estimate RMSE "
        f"{summary['ball_pos_rmse_m'] * 1000:.2f} mm, "
        f"{summary['ball_vel_rmse_mps'] * 1000:.1f} mm/s; terminated {summary['terminated']}"
    )


def _run_episode(
    env: gym.Env,
    controller,
    steps_wanted: int,
    seed: int,
    frame_every: int,
    frames_dir: Path,
    progress: bool,
) -> dict[str, Any]:
    """Reset, run the closed loop, save frames; the recorded truth and estimates."""
    start_m = START_DISTANCE_M * np.array(
        [np.cos(START_DIRECTION_RAD), np.sin(START_DIRECTION_RAD)]
    )
    obs, info = env.reset(seed=seed, options={"ball_pos_table_m": start_m})
    controller.reset()
    record: dict[str, Any] = {"time_s": [], "state": [], "estimate": [], "estimate_std": []}
    record["tilt_cmd_rad"] = []
    record["frame_paths"] = []
    record["start_ball_pos_table_m"] = start_m.tolist()

    def remember(obs: np.ndarray, info: dict) -> None:
        record["time_s"].append(round(float(info["time_s"]), 9))
        record["state"].append([float(v) for v in info["state"]])
        record["estimate"].append([float(v) for v in obs])
        std = np.sqrt(np.diag(info["estimate"]["covariance"]))
        record["estimate_std"].append([float(v) for v in std])

    def save_frame(step: int) -> None:
        frame = env.unwrapped.render()  # the camera frame the observer got at this step
        assert isinstance(frame, np.ndarray)  # the demo's env renders rgb_array
        record["frame_paths"].append(_save_frame(frame, frames_dir, step))

    remember(obs, info)
    save_frame(0)
    terminated = truncated = False
    step_time_s = 0.0
    steps = 0
    with progress_bar(total=steps_wanted, unit="step", desc="demo", disable=not progress) as bar:
        while steps < steps_wanted and not (terminated or truncated):
            tic_s = time.perf_counter()
            action, _ = controller.predict(obs)
            obs, _, terminated, truncated, info = env.step(action)
            step_time_s += time.perf_counter() - tic_s
            steps += 1
            record["tilt_cmd_rad"].append([float(v) for v in action])
            remember(obs, info)
            if steps % frame_every == 0:
                save_frame(steps)
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
    """Left: ball path in the table frame, truth and estimate. Middle: distance from the
    centre with the 1 cm band. Right: estimate minus truth per axis with the 2-sigma band."""
    time_s = np.array(record["time_s"])
    truth = np.array(record["state"])
    estimate = np.array(record["estimate"])
    std = np.array(record["estimate_std"])
    distance_m = np.linalg.norm(truth[:, BALL_POS], axis=1)

    fig = new_figure((15, 4.6))
    path_ax, dist_ax, err_ax = fig.subplots(1, 3, width_ratios=(1, 1.3, 1.3))

    draw_table(path_ax)
    path_ax.plot(truth[:, 0], truth[:, 1], color="tab:blue", lw=1.2, label="ball (truth)")
    path_ax.plot(
        estimate[:, 0], estimate[:, 1], color="tab:orange", lw=0.8, ls="--", label="estimate"
    )
    path_ax.plot(*truth[0, BALL_POS], "o", color="tab:blue", label="start")
    path_ax.set(xlabel="x table (m)", ylabel="y table (m)", title="Ball path, table frame")
    path_ax.set_aspect("equal")
    path_ax.legend(loc="upper right", fontsize=7)

    dist_ax.semilogy(time_s, np.maximum(distance_m, 1e-5), color="tab:blue", label="distance")
    dist_ax.axhline(TOLERANCE_M, color="tab:green", ls=":", label="1 cm")
    dist_ax.set(xlabel="time (s)", ylabel="distance from centre (m)", title="Pixel observer + LQR")
    tilt_ax = dist_ax.twinx()
    tilt_ax.plot(time_s, truth[:, TILT][:, 0], color="tab:orange", lw=0.8, label="tilt_x")
    tilt_ax.plot(time_s, truth[:, TILT][:, 1], color="tab:purple", lw=0.8, label="tilt_y")
    tilt_ax.set_ylabel("tilt (rad)")
    lines = dist_ax.get_lines() + tilt_ax.get_lines()
    dist_ax.legend(lines, [line.get_label() for line in lines], loc="upper right", fontsize=7)

    for axis, color in ((0, "tab:blue"), (1, "tab:red")):
        error_mm = (estimate[:, axis] - truth[:, axis]) * 1000
        band_mm = 2 * std[:, axis] * 1000
        name = "xy"[axis]
        err_ax.fill_between(time_s, -band_mm, band_mm, color=color, alpha=0.15)
        err_ax.plot(time_s, error_mm, color=color, lw=0.8, label=f"{name} error, ±2σ band")
    err_ax.set(
        xlabel="time (s)",
        ylabel="estimate − truth (mm)",
        title="Ball position estimate",
        ylim=(-1.5, 1.5),
    )
    err_ax.legend(loc="upper right", fontsize=7)
    save_figure(fig, path, dpi=110)
