"""The learned observers' median NEES/dof within [1/3, 3] under the sensor options inside
their networks' training ranges (noise, latency with jitter, drops), from measurements,
on seeds the training never drew (10**6 ...). The median NEES/dof beside each cell is
measured on 2026-11-29 with BallTable's and BallCatcher's variance scales fitted across
the consistency study's ranges (estimation/learned/variance_scale.py), the position RMSE
of ``learned`` on 2026-11-28 (the scale leaves its mean as it was); TargetFollower's
figures are of 2026-11-28. The ablation is in docs/learned_observers.md."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from ball_catcher_throws import intercept_throws
from closed_loop import closed_loop

from observer_gym.envs.target_follower import StateIndex

BAND = (1 / 3, 3.0)

# (observer, options): measured median NEES/dof (position RMSE)
BALL_TABLE = {
    ("learned", "noise 2 px"): {"measurement_noise_px": 2.0},  # 0.66 (4.4, 4.2 mm)
    ("learned", "latency"): {"latency_s": 0.04, "latency_jitter_s": 0.005},  # 0.59 (7.0 mm)
    ("learned", "drops"): {"frame_drop_prob": 0.2},  # 0.55 (3.9, 3.3 mm)
    ("learned-kf", "noise 2 px"): {"measurement_noise_px": 2.0},  # 1.19
    ("learned-kf", "latency"): {"latency_s": 0.04, "latency_jitter_s": 0.005},  # 0.94
    ("learned-kf", "drops"): {"frame_drop_prob": 0.2},  # 0.94
}
TARGET_FOLLOWER = {
    ("learned", "latency"): {"latency_s": 0.05, "latency_jitter_s": 0.01},  # 0.57 (1.5 px)
    ("learned", "drops"): {"frame_drop_prob": 0.1},  # 0.57 (1.3 px)
    ("learned-kf", "latency"): {"latency_s": 0.05, "latency_jitter_s": 0.01},  # 1.07 (2.4 px)
    ("learned-kf", "drops"): {"frame_drop_prob": 0.1},  # 0.67 (2.6 px)
}
# BallCatcher: measured with its scale by the age and the declared sensor and learned-kf's
# R twice that variance (2026-11-29, later than the others)
BALL_CATCHER = {
    ("learned", "latency"): {"latency_s": 0.01, "latency_jitter_s": 0.003},  # 0.91 (11 mm)
    ("learned", "drops"): {"frame_drop_prob": 0.1},  # 0.97 (13 mm)
    ("learned", "noise 2 px"): {"measurement_noise_px": 2.0},  # 1.01 (16 mm)
    ("learned-kf", "latency"): {"latency_s": 0.01, "latency_jitter_s": 0.003},  # 0.89
    ("learned-kf", "drops"): {"frame_drop_prob": 0.1},  # 0.89
}


def _ball_table(observer: str, options: dict[str, Any]) -> float:
    """The LQR, 3 episodes of 300 steps at 1 px unless given: median NEES/dof (8 entries)."""
    options = {"measurement_noise_px": 1.0, **options}
    nees = []
    for _, _, _, _, info in closed_loop(
        lambda: gym.make("observer_gym/BallTable-v0", obs_mode="measurements", **options),
        "lqr",
        range(10**6, 10**6 + 3),
        300,
        observer=observer,
    ):
        e = info["estimate"]["mean"] - info["state"]
        nees.append(e.dot(np.linalg.solve(info["estimate"]["covariance"], e)) / 8)
    return float(np.median(nees))


def _target_follower(observer: str, options: dict[str, Any]) -> float:
    """The VTC, 3 episodes of 300 steps at 2 px: median NEES/dof of the 6 image entries
    while the target is tracked."""
    options = {"measurement_noise_px": 2.0, **options}
    nees = []
    for _, estimate, _, _, info in closed_loop(
        lambda: gym.make("observer_gym/TargetFollower-v0", obs_mode="measurements", **options),
        "vtc",
        range(10**6, 10**6 + 3),
        300,
        quiet=(RuntimeWarning,),  # a singular stop
        observer=observer,
    ):
        tracked = info["state"][StateIndex.TRACKING_VALID] >= 0.5
        if not (tracked and estimate[StateIndex.TRACKING_VALID] >= 0.5):
            continue
        e = info["estimate"]["mean"][:6] - info["state"][:6]
        nees.append(e.dot(np.linalg.solve(info["estimate"]["covariance"][:6, :6], e)) / 6)
    assert len(nees) > 850, len(nees)
    return float(np.median(nees))


def _ball_catcher(observer: str, options: dict[str, Any]) -> float:
    """The intercept, 10 throws at 1 px unless given: median NEES/dof of the ball."""
    options = {"measurement_noise_px": 1.0, **options}
    throws = intercept_throws(
        lambda: gym.make("observer_gym/BallCatcher-v1", obs_mode="measurements", **options),
        observer,
        range(10**6, 10**6 + 10),
    )
    return float(np.median(throws.nees_per_dof))


@pytest.mark.slow
@pytest.mark.parametrize("cell", list(BALL_TABLE), ids=" ".join)
def test_ball_table(cell):
    nees = _ball_table(cell[0], BALL_TABLE[cell])
    assert BAND[0] <= nees <= BAND[1], nees


@pytest.mark.slow
@pytest.mark.parametrize("cell", list(TARGET_FOLLOWER), ids=" ".join)
def test_target_follower(cell):
    nees = _target_follower(cell[0], TARGET_FOLLOWER[cell])
    assert BAND[0] <= nees <= BAND[1], nees


@pytest.mark.slow
@pytest.mark.parametrize("cell", list(BALL_CATCHER), ids=" ".join)
def test_ball_catcher(cell):
    nees = _ball_catcher(cell[0], BALL_CATCHER[cell])
    assert BAND[0] <= nees <= BAND[1], nees


@pytest.mark.slow
def test_ball_catcher_learned_kf_at_2_px():
    """At 2 px, the edge of the network's training range: 1.03 (2.41 with the scale by the
    age alone and R once, 3.72 before the network's variance was scaled at all,
    estimation/learned/variance_scale.py; learned-kf's R is twice learned's scaled
    variance)."""
    nees = _ball_catcher("learned-kf", {"measurement_noise_px": 2.0})
    assert BAND[0] <= nees <= BAND[1], nees
