"""BallCatcher's learned observers at 4 px of pixel noise, the consistency study's largest,
past the network's training range (estimation/ball_catcher/learned.py,
``TRAINING_RANGES``: 0-2 px): the shipped weights were trained with the code's ranges,
and at 4 px both observers claim less error than they have (median NEES/dof above 3 on
throws the training and the variance scale's fit never drew: seeds 10**6 to 10**6 + 9,
the ``intercept`` controller on the observer's estimate, the ball's six entries from 0.1
s to the box's plane). Strict xfails: they pass, and must be turned into plain tests,
once a network holds the band there.

Measured 2026-11-29 (docs/results/consistency.md, "What stays out"): `learned` 4.51,
`learned-kf` 5.85 with the shipped network. A network retrained with the noise widened
to 0-4 px gave 2.06 and 4.33 here, but on 100 throws at 1 px its lateral error grew (y
6.6 mm against 5.6 for `learned`, 8.5 against 6.0 for `learned-kf`) and its catches fell
(22 and 20 of 100 against 29 and 50), so it was not shipped."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
from ball_catcher_throws import intercept_throws

from observer_gym.estimation.ball_catcher.learned import TRAINING_RANGES, WEIGHTS

pytest.importorskip("torch")

BAND = (1 / 3, 3.0)


def test_the_shipped_weights_were_trained_with_the_codes_ranges():
    report = json.loads(WEIGHTS.with_suffix(".json").read_text())
    assert report["training_ranges"] == {k: list(v) for k, v in TRAINING_RANGES.items()}


def _median_nees_per_dof(observer: str, noise_px: float) -> float:
    throws = intercept_throws(
        lambda: gym.make(
            "observer_gym/BallCatcher-v1", obs_mode="measurements", measurement_noise_px=noise_px
        ),
        observer,
        range(10**6, 10**6 + 10),
    )
    return float(np.median(throws.nees_per_dof))


@pytest.mark.slow
@pytest.mark.xfail(
    strict=True,
    reason="4 px is past the network's training range (0-2 px): learned 4.51, "
    "learned-kf 5.85 (the module docstring)",
)
@pytest.mark.parametrize("observer", ["learned", "learned-kf"])
def test_at_4_px_the_median_nees_per_dof_is_in_the_band(observer):
    nees = _median_nees_per_dof(observer, 4.0)
    assert BAND[0] <= nees <= BAND[1], nees
