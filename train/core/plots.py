"""Plots of closed-loop runs, from recorded arrays (matplotlib's Agg canvas; no
pyplot, so no global figure state)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from observer_gym.envs.ball_table.geometry import BALL_TRAVEL_M, TABLE_SIDE_M
from observer_gym.train.core.atomic_write import replace_atomically
from observer_gym.train.core.metrics import TOLERANCE_M

DPI = 110
MIN_LOG_DISTANCE_M = 1e-5  # distances are drawn on a log axis; exact zeros are lifted here


def save_figure(fig: Figure, path: str | Path, dpi: float = DPI) -> None:
    """Save ``fig`` to ``path`` in the format of its suffix, atomically
    (:func:`~observer_gym.train.core.atomic_write.replace_atomically`): a failed or interrupted save
    leaves no partial image."""
    path = Path(path)
    fmt = path.suffix.lstrip(".") or "png"
    replace_atomically(path, lambda tmp: fig.savefig(tmp, dpi=dpi, format=fmt))


def new_figure(figsize: tuple[float, float]) -> Figure:
    """A constrained-layout figure on its own Agg canvas (no pyplot state)."""
    fig = Figure(figsize=figsize, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def draw_table(ax: Axes) -> None:
    """The table's edge, the square the ball's centre can reach and the 1 cm band, in the
    table frame (m)."""
    squares: list[tuple[float, dict[str, Any]]] = [
        (
            TABLE_SIDE_M / 2,
            {"color": "k", "lw": 1.5, "label": f"table edge (±{TABLE_SIDE_M / 2} m)"},
        ),
        (
            BALL_TRAVEL_M,
            {"color": "0.5", "ls": "--", "lw": 1, "label": f"reachable (±{BALL_TRAVEL_M:g} m)"},
        ),
    ]
    for half_side_m, style in squares:
        xs = half_side_m * np.array([1, -1, -1, 1, 1])
        ys = half_side_m * np.array([1, 1, -1, -1, 1])
        ax.plot(xs, ys, **style)
    phase_rad = np.linspace(0.0, 2.0 * np.pi, 100)
    ax.plot(
        TOLERANCE_M * np.cos(phase_rad),
        TOLERANCE_M * np.sin(phase_rad),
        color="k",
        ls=":",
        lw=1,
        label=f"{TOLERANCE_M * 100:g} cm from centre",
    )


def plot_paths(
    ball_pos_m: Sequence[np.ndarray],
    path: Path,
    labels: Sequence[str] | None = None,
    title: str = "Ball path, table frame",
) -> None:
    """The ball's path (each a (T, 2) array) on the table, start 'o' and end 'x' marked,
    with the table's edge, the ball's reachable square and the 1 cm band drawn."""
    fig = new_figure((8.0, 6.0))
    ax = fig.subplots()
    draw_table(ax)
    labels = labels or [f"episode {i}" for i in range(len(ball_pos_m))]
    for i, (pos_m, label) in enumerate(zip(ball_pos_m, labels, strict=True)):
        color = f"C{i % 10}"
        pos_m = np.asarray(pos_m)
        ax.plot(pos_m[:, 0], pos_m[:, 1], color=color, lw=1.2, label=label)
        ax.plot(*pos_m[0], "o", color=color, ms=6)
        ax.plot(*pos_m[-1], "x", color=color, ms=7)
    ax.plot([], [], "o", color="0.3", label="start")
    ax.plot([], [], "x", color="0.3", label="end")
    ax.set(xlabel="x table (m)", ylabel="y table (m)", title=title)
    margin_m = 0.01
    limit_m = TABLE_SIDE_M / 2 + margin_m
    ax.set(xlim=(-limit_m, limit_m), ylim=(-limit_m, limit_m))
    ax.set_aspect("equal")
    ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8)  # off the table
    save_figure(fig, path)


def plot_distances(
    time_s: Sequence[np.ndarray],
    distance_m: Sequence[np.ndarray],
    path: Path,
    title: str = "Ball distance from the table's centre",
) -> None:
    """Distance from the centre over time for every episode (log axis), 1 cm line drawn."""
    fig = new_figure((8.0, 4.5))
    ax = fig.subplots()
    many = len(distance_m) > 10
    for i, (t_s, d_m) in enumerate(zip(time_s, distance_m, strict=True)):
        ax.plot(
            t_s,
            np.maximum(d_m, MIN_LOG_DISTANCE_M),
            color="tab:blue" if many else f"C{i % 10}",
            lw=0.8 if many else 1.2,
            alpha=0.4 if many else 1.0,
            label=None if many else f"episode {i}",
        )
    ax.axhline(TOLERANCE_M, color="k", ls="--", lw=1, label=f"{TOLERANCE_M * 100:g} cm")
    ax.set_yscale("log")
    ax.set(xlabel="time (s)", ylabel="distance (m)", title=title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(loc="upper right", fontsize=7, ncols=2)
    save_figure(fig, path)


def plot_estimate(
    time_s: np.ndarray,
    truth_pos_m: np.ndarray,
    estimate_pos_m: np.ndarray,
    estimate_std_m: np.ndarray,
    path: Path,
    title: str = "Observer estimate of the ball position",
) -> None:
    """Top: estimate vs truth of ball x and y with the estimate's ±2σ band. Bottom: the
    error (estimate - truth, mm) with the same band around zero. Arrays are (T, 2)."""
    t_s = np.asarray(time_s)
    truth, mean, std = (np.asarray(a) for a in (truth_pos_m, estimate_pos_m, estimate_std_m))
    fig = new_figure((11.0, 6.5))
    axes = fig.subplots(2, 2, sharex=True)
    for axis, name in enumerate(("x", "y")):
        top, bottom = axes[0, axis], axes[1, axis]
        top.fill_between(
            t_s,
            mean[:, axis] - 2 * std[:, axis],
            mean[:, axis] + 2 * std[:, axis],
            color="tab:orange",
            alpha=0.3,
            lw=0,
            label="estimate ±2σ",
        )
        top.plot(t_s, truth[:, axis], color="k", lw=1.2, label="truth")
        top.plot(t_s, mean[:, axis], color="tab:orange", lw=1, ls="--", label="estimate")
        top.set(ylabel=f"ball {name} (m)", title=f"ball {name}")
        top.legend(loc="upper right", fontsize=7)
        error_mm = 1e3 * (mean[:, axis] - truth[:, axis])
        band_mm = 2e3 * std[:, axis]
        bottom.fill_between(
            t_s, -band_mm, band_mm, color="tab:orange", alpha=0.3, lw=0, label="±2σ"
        )
        bottom.plot(t_s, error_mm, color="tab:red", lw=0.8, label="estimate - truth")
        bottom.axhline(0.0, color="k", lw=0.5)
        limit_mm = 1.2 * max(np.percentile(np.abs(error_mm), 99), np.median(band_mm), 1e-3)
        bottom.set_ylim(-limit_mm, limit_mm)  # the first frames' wide band would flatten it
        bottom.set(xlabel="time (s)", ylabel=f"error {name} (mm)")
        bottom.legend(loc="upper right", fontsize=7)
    fig.suptitle(title)
    save_figure(fig, path)


def plot_learning_curve(csv_path: Path, path: Path, config: dict) -> None:
    """The evaluation curve of a training run (``eval.csv``): mean return of the
    deterministic policy with +-1 std over its evaluation episodes, against env steps."""
    rows = np.genfromtxt(csv_path, delimiter=",", names=True, ndmin=1)
    fig = new_figure((7.0, 4.0))
    ax = fig.subplots()
    steps, mean, std = rows["timesteps"], rows["return_mean"], rows["return_std"]
    ax.plot(steps, mean, marker="o", ms=3, color="tab:blue", label="mean return")
    ax.fill_between(steps, mean - std, mean + std, color="tab:blue", alpha=0.2, label="+-1 std")
    ax.set(
        xlabel="env steps",
        ylabel=f"return ({int(rows['episodes'][-1])} evaluation episodes)",
        title=f"{config['algo'].upper()} on {config['env_id']}, obs {config['obs']}",
    )
    ax.grid(True, alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    save_figure(fig, path)
