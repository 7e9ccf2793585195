"""Options that cannot finish an episode or start an invalid world: BallCatcher's time
limit in seconds (its episode length follows control_dt_s and the flight times), and
launches or starts the env refuses at construction."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import observer_gym.envs  # noqa: F401  (registers the envs)
from observer_gym.controllers import make_controller
from observer_gym.envs.ball_catcher import BallCatcherConfig
from observer_gym.envs.ball_catcher import geometry as geo
from observer_gym.envs.target_follower.config import TargetFollowerConfig

CATCHER = "observer_gym/BallCatcher-v1"


def oracle_intercept(seeds, **options):
    """(outcome, truncated, steps) of each seed's episode: the intercept controller on
    the ground-truth state."""
    env = gym.make(CATCHER, obs_mode="state", **options)
    controller = make_controller("intercept", env)
    ends = []
    for seed in seeds:
        obs, info = env.reset(seed=seed)
        controller.reset()
        terminated = truncated = False
        steps = 0
        while not (terminated or truncated):
            action, _ = controller.predict(obs)
            obs, _, terminated, truncated, info = env.step(action)
            steps += 1
        ends.append((info["outcome"], truncated, steps))
    env.close()
    return ends


def test_default_episode_length_is_200_steps():
    # the published figures' episode: 2 s at the default 100 Hz
    config = BallCatcherConfig()
    assert config.time_limit_s == 2.0
    assert config.max_episode_steps == 200
    env = gym.make(CATCHER, obs_mode="state")
    env.reset(seed=0)
    zero = np.zeros(3, np.float32)
    # the box held still: the ball misses and the episode ends before the limit
    terminated = truncated = False
    steps = 0
    while not (terminated or truncated):
        _, _, terminated, truncated, info = env.step(zero)
        steps += 1
    env.close()
    assert steps < 200 and terminated and info["outcome"] == "missed"
    # thrown straight up from 2 m out, the ball flies for 4 s: cut at 200 steps, 2 s
    env = gym.make(CATCHER, obs_mode="state")
    env.reset(seed=0, options={"throw": ([2.0, 0.0, 1.0], [0.0, 0.0, 20.0])})
    ends = [env.step(zero)[2:4] for _ in range(200)]
    env.close()
    assert ends == [(False, False)] * 199 + [(False, True)]


def test_a_fine_control_period_still_catches():
    # 200 steps of 2 ms end at 0.4 s, before the ball arrives (0.40-0.48 s): the limit is
    # 2 s whatever the step, so 1000 steps
    assert BallCatcherConfig(control_dt_s=0.002).max_episode_steps == 1000
    ends = oracle_intercept(range(3), control_dt_s=0.002)
    assert [outcome for outcome, _, _ in ends] == ["caught"] * 3, ends


def test_long_flights_end_before_the_time_limit():
    # 2.5-3 s flights arrive after 200 steps of 10 ms: the limit is the longest flight
    # and 1.52 s after it
    config = BallCatcherConfig(flight_time_min_s=2.5, flight_time_max_s=3.0)
    assert config.time_limit_s == pytest.approx(4.52)
    assert config.max_episode_steps == 452
    ends = oracle_intercept(range(3), flight_time_min_s=2.5, flight_time_max_s=3.0)
    for outcome, truncated, steps in ends:
        assert outcome != "flying" and not truncated, ends
        assert 250 <= steps < 452


def test_a_time_limit_given_to_gym_make_still_cuts_the_episode():
    env = gym.make(CATCHER, obs_mode="state", max_episode_steps=10)
    env.reset(seed=0)
    for _ in range(10):
        *_, terminated, truncated, _ = env.step(np.zeros(3, np.float32))
    env.close()
    assert truncated and not terminated


def test_the_env_truncates_itself_without_gym_make():
    # built directly (no TimeLimit wrapper): its own limit, in steps of its control_dt_s
    from observer_gym.envs.ball_catcher import BallCatcherEnv

    env = BallCatcherEnv(obs_mode="state", control_dt_s=0.05, physics_dt_s=0.001)
    assert env.max_episode_steps == 40
    # thrown straight up from 2 m out, the ball flies for 4 s: cut at 40 steps, 2 s
    env.reset(seed=0, options={"throw": ([2.0, 0.0, 1.0], [0.0, 0.0, 20.0])})
    ends = [env.step(np.zeros(3, np.float32))[2:4] for _ in range(41)]
    env.close()
    assert ends[:40] == [(False, False)] * 39 + [(False, True)]
    assert ends[40] == (False, True)  # stepped on past it: still truncated


@pytest.mark.parametrize(
    ("options", "named"),
    [
        ({"launch_height_m": 0.0, "launch_spread_m": 1.0}, "launch_height_m"),
        ({"launch_height_m": 0.2, "launch_spread_m": 0.1}, "launch_spread_m"),
        ({"launch_x_m": 1.5, "launch_height_m": 1.5, "launch_spread_m": 1.0}, "launch_x_m"),
    ],
)
def test_launches_out_of_the_world_are_refused(options, named):
    with pytest.raises(ValueError, match=named) as refused:
        BallCatcherConfig(**options)
    message = str(refused.value)
    assert "launch_spread_m" in message and "allowed" in message
    with pytest.raises(ValueError, match=named):
        gym.make(CATCHER, **options)


def test_the_lowest_allowed_launch_is_taken_and_flies():
    lowest = geo.MISS_HEIGHT_M + 0.1
    env = gym.make(CATCHER, obs_mode="state", launch_height_m=lowest, launch_spread_m=0.1)
    for seed in range(20):
        _, info = env.reset(seed=seed)
        assert info["throw"]["launch_pos_world"][2] >= geo.MISS_HEIGHT_M
        _, _, terminated, _, info = env.step(np.zeros(3, np.float32))
        assert not terminated and info["outcome"] == "flying"
    env.close()


def test_a_target_starting_inside_the_stop_distance_is_refused():
    with pytest.raises(ValueError, match=r"start_distance_min_m.*min_distance_m") as refused:
        TargetFollowerConfig(start_distance_min_m=0.5, min_distance_m=1.0)
    assert "allowed" in str(refused.value)
    with pytest.raises(ValueError, match="start_bearing_max_rad"):  # 1.1 cos 0.6 = 0.91
        TargetFollowerConfig(start_bearing_max_rad=0.6, min_distance_m=1.0)
    TargetFollowerConfig(start_distance_min_m=1.1, min_distance_m=1.0)  # 1.08 m: taken
    # the depth the env starts the target at is never within the stop distance
    env = gym.make(
        "observer_gym/TargetFollower-v0",
        obs_mode="state",
        start_distance_min_m=1.05,
        start_bearing_max_rad=0.2,
        min_distance_m=1.0,
    )
    for seed in range(10):
        env.reset(seed=seed)
        _, _, terminated, _, _ = env.step(np.zeros(env.action_space.shape, np.float32))
        assert not terminated
    env.close()
