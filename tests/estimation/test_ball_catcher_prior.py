"""BallCatcher's filters start from the declared throw distribution
(``observer.throw_prior``) and run on the ball's state alone when no calibration error is
declared (the consider parameters then add nothing)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from observer_gym.envs.ball_catcher.config import BallCatcherConfig
from observer_gym.envs.ball_catcher.throws import sample_throw
from observer_gym.estimation.ball_catcher import BallCatcherObserver, PixelEKFObserver
from observer_gym.estimation.ball_catcher.observer import throw_prior, wide_prior

ENV_ID = "observer_gym/BallCatcher-v1"
SAMPLES = 50_000


@pytest.mark.parametrize(
    "options",
    [
        {},
        {"launch_spread_m": 0.3, "target_radius_m": 0.2, "flight_time_max_s": 0.9},
        {"flight_time_min_s": 0.45, "flight_time_max_s": 0.45},  # one flight time
    ],
)
def test_the_throw_prior_is_the_mean_and_covariance_of_sampled_throws(options):
    config = BallCatcherConfig(**options)
    rng = np.random.default_rng(0)
    throws = [sample_throw(config, rng) for _ in range(SAMPLES)]
    states = np.array([np.r_[t.launch_pos_world, t.launch_vel_world] for t in throws])
    x0, P0 = throw_prior(config)
    std = np.sqrt(np.diag(P0))
    # the sample mean within 5 standard errors, the sample covariance within 2 %
    np.testing.assert_array_less(np.abs(states.mean(axis=0) - x0), 5.0 * std / np.sqrt(SAMPLES))
    sample_cov = np.cov(states.T)
    assert np.abs(sample_cov - P0).max() <= 0.02 * np.abs(P0).max()
    np.testing.assert_allclose(np.sqrt(np.diag(sample_cov)), std, rtol=0.02)


def test_the_wide_prior_has_the_throw_priors_mean_and_10_m_and_10_mps():
    config = BallCatcherConfig()
    x0, P0 = wide_prior(config)
    np.testing.assert_array_equal(x0, throw_prior(config)[0])
    np.testing.assert_array_equal(P0, np.diag([100.0] * 6))


@pytest.mark.parametrize("observer", [BallCatcherObserver, PixelEKFObserver])
@pytest.mark.parametrize(("calibration", "dim"), [({}, 6), ({"calib_rotation_error_deg": 1.0}, 12)])
def test_the_filter_state_holds_three_rotation_parameters_per_camera_when_declared(
    observer, calibration, dim
):
    env = gym.make(ENV_ID, obs_mode="measurements", **calibration).unwrapped
    try:
        pipeline = observer(env)
        kf = pipeline.filter.kf if observer is BallCatcherObserver else pipeline.core.ekf
        assert kf.dim_x == dim
        np.testing.assert_array_equal(kf.x[:6], throw_prior(env.config)[0])
    finally:
        env.close()
