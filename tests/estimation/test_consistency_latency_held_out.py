"""BallTable ``kf`` and ``kf-latency`` under latency with jitter on seeds no change was
tuned on (issue 45): median episode NEES/dof within [1/3, 3] at latency_s 0, 0.05, 0.1
and 0.15 s with a latency jitter of 0.01 s, seeds 200-203 (the tuning and the ablation
used seeds 0-7 and 100-107: benchmarks/latency_consistency_ablation.py), the consistency
study's conditions (the LQR, 300 steps, pushes at 0.5 Hz, the perfect detector's
measurements). Each cell is 4 episodes, 15-40 s: all ``slow``.

What sets these cells (docs/results/consistency.md, "What moved, what it costs"): the
ball's block reads what the episode's pushes make of it. Its Q takes the pushes as
white noise of their exact variance (:func:`test_the_pushes_share_of_q_is_their_variance`
below), which the filter claims at every step while on perfect pixels the error is
near zero between pushes and far above the claim in the steps after one, so an
episode's NEES follows the push energy its seed drew: seeds 100-107 drew 31 % of the
expected (10 pushes in 8 episodes against 24), and read 0.24-0.29 per dof in the ball's
block where seeds 0-7 (94 %) read 0.82-1.02. Seeds 200-203 drew 116 %, 11 %, 26 % and
278 % of it (2, 4, 2 and 7 pushes). Measured with this code (median; episodes 200-203):
kf 0.40 (0.62, 0.19, 0.16, 0.97), 0.54, 0.82 and 1.45 (1.50, 1.13, 1.41, 2.42) at 0,
0.05, 0.1 and 0.15 s; kf-latency 0.41 (0.62, 0.13, 0.20, 1.07), 0.59, 0.59 and 0.66
(0.97, 0.16, 0.35, 1.69): the two seeds with little pushing read 0.13-0.35.

The fast tests: the pushes' share of Q against draws of the env's pushes, and the tilt
filter's Q (observer.py ``tilt_departure_q``) against its closed form; the slow one
checks that Q against the arm's departure from the lag model in the simulator.
"""

from __future__ import annotations

import numpy as np
import pytest
from consistency_cells import HIGH, LOW

from observer_gym.envs.ball_table.config import BallTableConfig
from observer_gym.estimation.ball_table import observer as ball_table_observer
from observer_gym.estimation.ball_table.models import ROLLING_ACCEL_FACTOR, TiltLagModel
from observer_gym.estimation.ball_table.noise import BALL_MASS_KG, ball_process_params
from observer_gym.train.experiments.consistency_study import SYSTEMS, measure_consistency
from observer_gym.train.experiments.episode import EpisodeSpec, run_episode

LATENCY_JITTER_S = 0.01
LATENCIES_S = (0.0, 0.05, 0.1, 0.15)
HELD_OUT_SEED, EPISODES = 200, 4
# Measured outside the band on the held-out seeds and left open: none.
OUTSIDE: dict[tuple[str, float], str] = {}


def _cells() -> list:
    params = []
    for family in ("kf", "kf-latency"):
        for latency in LATENCIES_S:
            marks = [pytest.mark.slow]
            if (family, latency) in OUTSIDE:
                marks.append(
                    pytest.mark.xfail(
                        strict=True, raises=AssertionError, reason=OUTSIDE[(family, latency)]
                    )
                )
            params.append(pytest.param(family, latency, marks=marks))
    return params


@pytest.mark.parametrize(("family", "latency_s"), _cells())
def test_median_nees_per_dof_is_within_the_band_on_held_out_seeds(family, latency_s):
    study = SYSTEMS["BallTable-v0"]
    env_kwargs = {
        **study.env_kwargs,
        "latency_s": latency_s,
        "latency_jitter_s": LATENCY_JITTER_S,
    }
    run = measure_consistency(
        "observer_gym/BallTable-v0",
        f"{family}-measurements",
        study.controller,
        EPISODES,
        study.steps,
        env_kwargs,
        seed=HELD_OUT_SEED,
    )
    print(f"\n{family} at {latency_s} s: NEES/dof {run.nees_ratios}")
    assert LOW <= run.median_nees_ratio <= HIGH, run.median_nees_ratio


def test_the_pushes_share_of_q_is_their_variance():
    """w1's pushes' share, rate E[dv_i^2], against 200 000 pushes drawn as the env draws
    them (envs/ball_table/disturbances.py: magnitude uniform in [0, J], direction
    uniform; the ball rolls on at 5/7 of J / m): within 1 %."""
    config = BallTableConfig(push_rate_hz=0.5, push_impulse_ns=0.005)
    rng = np.random.default_rng(0)
    n = 200_000
    angle = rng.uniform(0.0, 2.0 * np.pi, n)
    speed = ROLLING_ACCEL_FACTOR * rng.uniform(0.0, config.push_impulse_ns, n) / BALL_MASS_KG
    per_axis = 0.5 * np.mean(speed**2)  # E[dv_x^2] = E[dv_y^2] = E[|dv|^2] / 2
    assert np.mean((speed * np.cos(angle)) ** 2) == pytest.approx(per_axis, rel=0.01)

    def q_w1(cfg):
        params = ball_process_params(cfg, 3e-4, 0.006)
        return params.sigma_w**2 * params.w1_psd_time_s

    pushes_share = q_w1(config) - q_w1(BallTableConfig(push_rate_hz=0.0))
    assert pushes_share == pytest.approx(config.push_rate_hz * per_axis, rel=0.01)


def test_the_tilt_filter_s_q_is_the_measured_departure():
    """Over a 20 ms step at rest: the floors' variance; with an angular acceleration
    alpha: plus (c alpha)^2 on each axis; over 10 ms half of each (white)."""
    floor = np.square(ball_table_observer.TILT_DEPARTURE_FLOOR_RAD)
    coef = np.square(ball_table_observer.TILT_DEPARTURE_ALPHA_COEF_S2)
    np.testing.assert_allclose(
        np.diag(ball_table_observer.tilt_departure_q(np.zeros(2), 0.02)), floor
    )
    alpha = np.array([3.0, -4.0])  # |alpha| = 5 rad/s^2
    Q = ball_table_observer.tilt_departure_q(alpha, 0.01)
    np.testing.assert_allclose(np.diag(Q), 0.5 * (floor + 25.0 * coef))
    assert Q[0, 1] == Q[1, 0] == 0.0


@pytest.mark.slow
def test_the_tilt_departure_model_claims_the_sim():
    """The arm's one-step departure from the lag model, e = theta(k+1) - Phi theta(k) -
    Gamma u(k) (the truth), against the variance ``tilt_departure_q`` claims from the
    lag model's angular acceleration, over the 8 episodes it was fitted on (the study's
    LQR with pushes, seeds 0-7): mean(e^2) / mean(s^2) per axis 0.56 and 0.63 at the
    fit (0.7-0.8 over the first 15 steps, 0.1-0.3 after: the acceleration term claims
    more than the calm steps' error; seeds 0-2 alone 0.24 and 0.81, the first steps'
    swings differ from seed to seed). The 0.02 rad/s white rate noise it replaced
    claimed 10^4-10^5 times the error's variance once calm."""
    config = BallTableConfig()
    lag = TiltLagModel.from_arm(config.arm_position_gain, config.physics_dt_s, 0.0)
    Phi, Gamma, _ = lag.matrices(config.dt_s)
    study = SYSTEMS["BallTable-v0"]
    errors, claimed = [], []
    for seed in range(8):
        spec = EpisodeSpec.of(
            "BallTable-v0",
            "kf-measurements",
            study.controller,
            seed,
            max_steps=study.steps,
            env_kwargs=dict(study.env_kwargs),
        )
        record = run_episode(spec)
        tilt, actions = record["state"][:, 4:6], record["actions"]
        lag_tilt, command = tilt[0].copy(), np.zeros(2)
        for k in range(len(actions)):
            errors.append(tilt[k + 1] - Phi @ tilt[k] - Gamma @ actions[k])
            rate_before = lag.rate(lag_tilt, command)
            lag_tilt, command = Phi @ lag_tilt + Gamma @ actions[k], actions[k]
            alpha = (lag.rate(lag_tilt, command) - rate_before) / config.dt_s
            claimed.append(np.diag(ball_table_observer.tilt_departure_q(alpha, config.dt_s)))
    ratio = np.mean(np.square(errors), axis=0) / np.mean(claimed, axis=0)
    print(f"\nmean(e^2) / mean(s^2): {ratio}")
    assert np.all((ratio > 0.3) & (ratio < 1.5)), ratio
