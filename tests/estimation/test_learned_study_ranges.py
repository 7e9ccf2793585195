"""The learned observers' median NEES/dof within [1/3, 3] at consistency-study conditions
beyond their networks' training ranges, held there by the variance scale fitted on
validation throws drawn across the study's ranges (estimation/learned/variance_scale.py,
``benchmarks/learned_variance_scale.py --ranges study --estimator geometric``; for
BallCatcher by the newest frame's age and the declared sensor's pixel noise, drops and
calibration errors, ``--by-age 0,0.05,0.1,0.2 --by-declared ...``, seeds
3000000-3000499; the study's seeds are 0-4, these 10**6 to 10**6 + 9), and the same
scale's other side: at 0 px, inside the training range, it does not make ``learned``
claim too much. Against the simulator's truth, from measurements, BallCatcher's
``intercept``. Measured on 2026-11-29, median NEES/dof with the scale (in brackets: with
BallCatcher's earlier scale by the age alone, held at its constant up to 0.05 s, and
``learned-kf``'s R once that variance)."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from ball_catcher_throws import intercept_throws

BAND = (1 / 3, 3.0)
LATENCY = {"latency_jitter_s": 0.01}  # the consistency study's jitter on its latency sweep

# (observer, cell): the env options on top of 0 px (the study's default)
BALL_CATCHER = {
    # training range 0-0.01 s: 2.67 (1.18; 2.73 with the constant scale alone, 3.99 with
    # none). At 0 px the noise term shrinks a variance the latency's error dominates: the
    # additive model's edge (estimation/learned/variance_scale.py)
    ("learned", "latency 0.15 s"): {"latency_s": 0.15, **LATENCY},
    # twenty times the training range: 2.77 (1.12; 3.21 with the constant scale alone)
    ("learned", "latency 0.2 s"): {"latency_s": 0.2, **LATENCY},
    # training range 0-0.1: 1.97 (1.81; 3.52 without a scale)
    ("learned", "drops 0.5"): {"frame_drop_prob": 0.5},
    # inside the training range: 1.79 (0.35, near the band's lower edge then)
    ("learned", "0 px"): {},
    # 1.52 (0.86)
    ("learned-kf", "0 px"): {},
    # 1.34 (1.24; 1.96 with the constant scale alone, 1.76 with none)
    ("learned-kf", "latency 0.2 s"): {"latency_s": 0.2, **LATENCY},
}


def _ball_catcher(observer: str, options: dict[str, Any]) -> float:
    """The intercept, 10 throws at 0 px unless given: median NEES/dof of the ball."""
    options = {"measurement_noise_px": 0.0, **options}
    throws = intercept_throws(
        lambda: gym.make("observer_gym/BallCatcher-v1", obs_mode="measurements", **options),
        observer,
        range(10**6, 10**6 + 10),
    )
    return float(np.median(throws.nees_per_dof))


@pytest.mark.slow
@pytest.mark.parametrize("cell", list(BALL_CATCHER), ids=" ".join)
def test_ball_catcher(cell):
    nees = _ball_catcher(cell[0], BALL_CATCHER[cell])
    assert BAND[0] <= nees <= BAND[1], nees


# BallTable `learned` at four times its training latency (0-0.05 s), held in the band by the
# scale by the newest frame's age (``--by-age``): the study's cell (the LQR, 300 steps,
# pushes at 0.5 Hz, 0.01 s of jitter), on seeds the fit (3000000 on) and the study (0-4)
# did not draw. Measured on 2026-11-29, median of 5 episodes: 1.41 (4.75 with the one
# constant scale before it, estimation/ball_table/learned.json on main then).
BALL_TABLE_SEEDS = (10**6, 5)


@pytest.mark.slow
def test_ball_table_learned_at_0_2_s_of_latency():
    from observer_gym.train.experiments.consistency_study import (
        OPTION_ENV_KWARGS,
        SYSTEMS,
        measure_consistency,
    )

    study = SYSTEMS["BallTable-v0"]
    run = measure_consistency(
        "observer_gym/BallTable-v0",
        "learned-measurements",
        study.controller,
        BALL_TABLE_SEEDS[1],
        study.steps,
        {**study.env_kwargs, "latency_s": 0.2, **OPTION_ENV_KWARGS["latency_s"]},
        seed=BALL_TABLE_SEEDS[0],
    )
    assert BAND[0] <= run.median_nees_ratio <= BAND[1], run.nees_ratios
