"""BallTable-v0 in ``observer-gym run``: centre the ball (see the :class:`Task` interface)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from observer_gym.envs.ball_table.layout import BALL_POS
from observer_gym.train.core import metrics

# observer_gym.estimation.ball_table's observers other than the default (kf), each from
# the camera's frames and from the measurements (the learned ones read frames through
# their learned detector, measurements straight)
_FAMILY = ("kf-latency", "ekf", "raw", "oracle-visible", "learned", "learned-kf")
OBSERVERS: dict[str, tuple[str, dict[str, Any] | None]] = {
    "oracle": ("state", {}),
    "kf": ("rgb", {}),
    "kf-measurements": ("measurements", {}),
    **{
        f"{name}{suffix}": (obs_mode, {"observer": name})
        for name in _FAMILY
        for suffix, obs_mode in (("", "rgb"), ("-measurements", "measurements"))
    },
    "pixels": ("rgb", None),  # the camera frames, unfiltered: for agents trained on rgb
    # the newest delivered measurement, unfiltered: for agents trained on measurements
    "detections": ("measurements", None),
}
# what an agent trained with --obs estimate reads, by --estimate-from
ESTIMATE_OBSERVERS = {"measurements": "kf-measurements", "rgb": "kf"}
CONFIG = {"tolerance_m": metrics.TOLERANCE_M}
PATH_PLOT_EPISODES = 5  # path.png shows the first this many episodes

# summary key -> (label, unit, scale from the stored SI value to the shown unit, digits)
SUMMARY_ROWS: dict[str, tuple[str, str, float, int]] = {
    "episodes": ("episodes", "", 1.0, 0),
    "fraction_settled": ("fraction settled (1 cm)", "", 1.0, 2),
    "settling_time_mean_s": ("settling time, mean (settled)", "s", 1.0, 2),
    "settling_time_median_s": ("settling time, median (settled)", "s", 1.0, 2),
    "settling_time_max_s": ("settling time, max (settled)", "s", 1.0, 2),
    "mean_distance_m": ("distance from centre, mean", "mm", 1e3, 2),
    "final_distance_m": ("final distance from centre, mean", "mm", 1e3, 2),
    "time_within_s": ("time within 1 cm, mean", "s", 1.0, 2),
    "effort_rms_rad": ("control effort (RMS tilt command), mean", "mrad", 1e3, 2),
    "position_rmse_m": ("estimation RMSE position, mean", "mm", 1e3, 3),
    "velocity_rmse_mps": ("estimation RMSE velocity, mean", "mm/s", 1e3, 2),
    "return": ("return, mean", "", 1.0, 1),
    "solver_failures": ("solver failures (total)", "", 1.0, 0),
    "terminated": ("terminated (ball off the table)", "", 1.0, 0),
}
# observer-gym compare's table: episode metric -> (label, unit, scale from the stored SI
# value to the unit, digits, "lower" or "higher" is better); the first is the primary one
COMPARE_METRICS: dict[str, tuple[str, str, float, int, str]] = {
    "mean_distance_m": ("distance from centre", "mm", 1e3, 2, "lower"),
    "final_distance_m": ("final distance", "mm", 1e3, 2, "lower"),
    "settling_time_s": ("settling time to 1 cm", "s", 1.0, 2, "lower"),
    "time_within_s": ("time within 1 cm", "s", 1.0, 2, "higher"),
    "effort_rms_rad": ("effort (RMS tilt)", "mrad", 1e3, 2, "lower"),
    "position_rmse_m": ("estimate RMSE, position", "mm", 1e3, 3, "lower"),
    "return": ("return", "", 1.0, 1, "higher"),
}


def episode_metrics(record: Mapping[str, Any]) -> dict[str, Any]:
    """:func:`observer_gym.train.core.metrics.episode_metrics` of a run record."""
    return metrics.episode_metrics(
        record["time_s"],
        record["state"],
        record["actions"],
        record["rewards"],
        estimate=record["estimate"],
        terminated=record["terminated"],
        solver_failures=record["solver_failures"],
    )


summarize = metrics.summarize


def plot(records: Sequence[Mapping[str, Any]], observer: str, out_dir: Path) -> list[str]:
    """``path.png`` (ball paths of the first episodes), ``error.png`` (distance from the
    centre vs time) and, for an observer, ``estimate.png`` (episode 0's estimate vs truth
    with +-2 sigma)."""
    from observer_gym.train.core.plots import (  # imported on use: matplotlib
        plot_distances,
        plot_estimate,
        plot_paths,
    )

    shown = records[:PATH_PLOT_EPISODES]
    plot_paths(
        [r["state"][:, BALL_POS] for r in shown],
        out_dir / "path.png",
        title=f"Ball path, table frame (first {len(shown)} of {len(records)} episodes)",
    )
    plot_distances(
        [r["time_s"] for r in records],
        [metrics.distance_from_centre_m(r["state"][:, BALL_POS]) for r in records],
        out_dir / "error.png",
    )
    files = ["path.png", "error.png"]
    if records[0]["estimate"] is not None:
        first = records[0]
        plot_estimate(
            first["time_s"],
            first["state"][:, BALL_POS],
            first["estimate"][:, BALL_POS],
            first["estimate_std"][:, BALL_POS],
            out_dir / "estimate.png",
            title=f"Observer '{observer}' estimate of the ball position, episode 0",
        )
        files.append("estimate.png")
    return files
