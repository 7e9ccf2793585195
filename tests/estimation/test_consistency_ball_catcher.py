"""BallCatcher's estimating observers say how large their error is (issue 23): median
episode NEES/dof over the ball's free flight (up to its first touch of the box, where the
ballistic model stops holding) within [1/3, 3] under the sensor options, R x 100 outside.

Cells: 3 throws (seeds 0-2), the intercept controller on the observer's own estimate,
perfect-detector measurements; R from the declared pixel noise
(``SensorSpec.measurement_noise_std_px``). Measured with this code (median of the 3):
kf 0.50 at 0 px, 0.49 at 0.5 px, 0.67 at 2 px, 0.45 at 20 % drops; ekf 0.51, 0.65, 0.73,
0.50. With R x 100 at 2 px: 0.007 (kf), 0.008 (ekf). At 0 px R x 100 changes nothing
(0.49): the declared noise there is float32's, far below what the process noise adds.

Cells still outside the band are marked ``xfail(strict=True)`` with their measured value.
"""

from __future__ import annotations

import pytest
from consistency_cells import (
    CONDITIONS,
    HIGH,
    LOW,
    NOT_POSITIVE,
    assert_r_scale_refused,
    band_cells,
    median_nees,
)

ENV_ID = "observer_gym/BallCatcher-v0"
OBSERVERS = ("kf", "ekf")  # kf-latency is kf under a second name
EPISODES = 3
OUTSIDE = {
    ("kf", "latency"): "measured 0.32, just below the band; not yet analysed",
}
CELLS = [(o, c) for o in OBSERVERS for c in CONDITIONS]


def _median_nees(observer: str, env_kwargs: dict, **options) -> float:
    return median_nees(ENV_ID, observer, "intercept", EPISODES, None, env_kwargs, **options)


@pytest.mark.parametrize(("observer", "condition"), band_cells(CELLS, OUTSIDE))
def test_median_nees_per_dof_over_the_flight_is_within_the_band(observer, condition):
    ratio = _median_nees(f"{observer}-measurements", CONDITIONS[condition])
    assert LOW <= ratio <= HIGH, ratio


@pytest.mark.parametrize("observer", OBSERVERS)
def test_a_hundredfold_R_fails_the_band(observer):
    ratio = _median_nees(f"{observer}-measurements", CONDITIONS["2px"], r_scale=100.0)
    assert ratio < LOW, ratio


@pytest.mark.parametrize("bad", NOT_POSITIVE)
def test_r_scale_must_be_a_positive_number(make_env, bad):
    assert_r_scale_refused(make_env(ENV_ID, obs_mode="measurements"), OBSERVERS, bad)


@pytest.mark.parametrize("observer", OBSERVERS)
def test_from_rendered_frames_at_the_defaults(observer):
    """The rgb detector's error model in R (observer.rgb_pixel_std_px: 0.095 px on
    noiseless frames): measured medians 0.49 (kf), 0.56 (ekf); 0.14 and 0.16 with the
    0.2 px it took before."""
    ratio = _median_nees(observer, {})
    assert LOW <= ratio <= HIGH, ratio
