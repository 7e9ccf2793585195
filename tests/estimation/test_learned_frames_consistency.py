"""BallTable's ``learned`` from rendered frames within [1/3, 3] in two cells of the
consistency study's frames part (docs/results/consistency.md, "From rendered frames"),
held there by the ``"rgb"`` variance scale (estimation/learned/variance_scale.py), fitted
by ``benchmarks/learned_variance_scale.py --obs-mode rgb --ranges study --estimator
geometric`` on seeds 4000000-4000015; these run seeds 10**6 + 700 to 10**6 + 702, which
neither the fit nor the study (0-2) drew. The study's cell: the LQR, 300 steps, pushes at
0.5 Hz (train/experiments/consistency_study.py, SYSTEMS), median episode NEES/dof of 3.
Measured on 2026-11-29 (median, with the scale / without it): image_noise_std 16 0.91 /
7.53, latency 0.1 s 1.11 / 7.14; the study's cells (seeds 0-2) 0.95 and 2.01 with it,
7.82 and 14.67 without."""

from __future__ import annotations

import pytest
from consistency_cells import HIGH, LOW

from observer_gym.train.experiments.consistency_study import (
    OPTION_ENV_KWARGS,
    SYSTEMS,
    measure_consistency,
)

SEED = 10**6 + 700
EPISODES = 3
# (observer, cell): env options on top of the study's; measured median NEES/dof
CELLS = {
    ("learned", "image_noise_std 16"): {"image_noise_std": 16.0},
    ("learned", "latency 0.1 s"): {
        "latency_s": 0.1,
        **OPTION_ENV_KWARGS["latency_s"],
    },
    # four times the network's training latency, in the band by the scale by the age
    ("learned", "latency 0.2 s"): {"latency_s": 0.2, **OPTION_ENV_KWARGS["latency_s"]},
    ("learned-kf", "latency 0.2 s"): {"latency_s": 0.2, **OPTION_ENV_KWARGS["latency_s"]},
}


@pytest.mark.slow
@pytest.mark.parametrize("cell", list(CELLS), ids=" ".join)
def test_learned_from_frames_is_within_the_band(cell):
    study = SYSTEMS["BallTable-v0"]
    run = measure_consistency(
        "observer_gym/BallTable-v0",
        cell[0],
        study.controller,
        EPISODES,
        study.steps,
        {**study.env_kwargs, **CELLS[cell]},
        seed=SEED,
    )
    print(f"\n{cell}: NEES/dof {run.nees_ratios}")
    assert LOW <= run.median_nees_ratio <= HIGH, run.nees_ratios
