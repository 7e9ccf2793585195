"""Bad construction options and observations for every controller: ValueError naming the
option and what it allows (NumPy scalars accepted as numbers); the VTC's singular B_i
(zero width, overflow) gives the zero action and is reported; MPC's horizon is bounded."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from observer_gym.controllers import BallTableMPC, make_controller
from observer_gym.controllers.mpc import MAX_HORIZON, MPCController
from observer_gym.controllers.target_follower.vtc import VisualTrackingController
from observer_gym.envs.target_follower import IMAGE, STATE_DIM, StateIndex

BALL_TABLE = "observer_gym/BallTable-v0"
BALL_CATCHER = "observer_gym/BallCatcher-v1"
TARGET_FOLLOWER = "observer_gym/TargetFollower-v0"
ENV_OF = {
    "lqr": BALL_TABLE,
    "mpc": BALL_TABLE,
    "pid": BALL_TABLE,
    "intercept": BALL_CATCHER,
    "vtc": TARGET_FOLLOWER,
}
# Every numeric option: (controller, option, a valid value, whether None is allowed).
NUMERIC_OPTIONS = [
    ("mpc", "horizon", 10, False),
    ("mpc", "tilt_limit_rad", 0.05, True),
    ("mpc", "tilt_rate_limit_radps", 1.0, False),
    ("mpc", "ball_limit_m", 0.1, False),
    ("pid", "omega_radps", 2.0, False),
    ("pid", "damping", 0.8, False),
    ("pid", "kp", 4.0, True),
    ("pid", "ki", 1.0, True),
    ("pid", "kd", 3.0, True),
    ("intercept", "hold_std_m", 0.05, False),
    ("intercept", "brake_fraction", 0.8, False),
    ("intercept", "position_gain_per_s", 10.0, True),
    ("intercept", "aim_depth_m", 0.005, False),
    ("vtc", "singular_margin_px", 10.0, True),
]


@pytest.fixture
def env_for(make_env):
    made = {}

    def get(name):
        env_id = ENV_OF[name]
        if env_id not in made:
            made[env_id] = make_env(env_id, obs_mode="state")
        return made[env_id]

    return get


@pytest.mark.parametrize(("name", "option", "valid", "none_ok"), NUMERIC_OPTIONS)
def test_numeric_options_accept_numpy_scalars_and_reject_the_rest(
    env_for, name, option, valid, none_ok
):
    env = env_for(name)
    numpy_valid = np.int64(valid) if isinstance(valid, int) else np.float32(valid)
    for value in (valid, numpy_valid, np.array(valid)):
        controller = make_controller(name, env, **{option: value})
        assert float(getattr(controller, option)) == pytest.approx(float(valid), rel=1e-6)
    bad = [np.nan, np.inf, -np.inf, -1.0, "1", [valid], True, object()]
    if not none_ok:
        bad.append(None)
    for value in bad:
        with pytest.raises(ValueError, match=rf"{option} = .*must be"):
            make_controller(name, env, **{option: value})


def test_the_reported_type_errors_are_value_errors(env_for):
    """Before: TypeError / AttributeError."""
    with pytest.raises(ValueError, match="env = None, must be a gymnasium env"):
        make_controller("lqr", None)
    with pytest.raises(ValueError, match="damping = None, must be a finite number > 0"):
        make_controller("pid", env_for("pid"), damping=None)
    with pytest.raises(ValueError, match="horizon = None, must be an integer >= 1"):
        make_controller("mpc", env_for("mpc"), horizon=None)
    with pytest.raises(ValueError, match="hold_std_m = None, must be a finite number >= 0"):
        make_controller("intercept", env_for("intercept"), hold_std_m=None)
    with pytest.raises(ValueError, match="name"):
        make_controller(["lqr"], env_for("lqr"))


@pytest.mark.parametrize("margin", [-5.0, np.nan, np.inf, "5"])
def test_vtc_rejects_a_bad_singular_margin(env_for, margin):
    """Before: -5 and NaN were taken (NaN switched the singularity check off)."""
    with pytest.raises(ValueError, match="singular_margin_px"):
        make_controller("vtc", env_for("vtc"), singular_margin_px=margin)


def test_other_bad_options(env_for):
    with pytest.raises(ValueError, match="constrained = None, must be True or False"):
        make_controller("mpc", env_for("mpc"), constrained=None)
    with pytest.raises(ValueError, match="osqp_settings"):
        make_controller("mpc", env_for("mpc"), osqp_settings=[("max_iter", 10)])
    with pytest.raises(ValueError, match=r"brake_fraction = 1\.5"):
        make_controller("intercept", env_for("intercept"), brake_fraction=1.5)
    with pytest.raises(ValueError, match="gains"):
        make_controller("vtc", env_for("vtc"), gains="fast")
    with pytest.raises(ValueError, match="gains"):
        make_controller("vtc", env_for("vtc"), gains=None)
    with pytest.raises(ValueError, match="camera"):
        make_controller("vtc", env_for("vtc"), camera="default")
    for option in ("Q", "R"):
        with pytest.raises(ValueError, match=rf"{option} = .*matrix of numbers"):
            make_controller("lqr", env_for("lqr"), **{option: object()})
        with pytest.raises(ValueError, match=rf"{option} = .*matrix of numbers"):
            make_controller("mpc", env_for("mpc"), **{option: "diag"})
    with pytest.raises(ValueError, match="plant must be a ConstrainedPlant"):
        MPCController(env_for("mpc"))
    with pytest.raises(ValueError, match="plant must be a BallTablePlant"):
        BallTableMPC(env_for("mpc"))
    with pytest.raises(ValueError, match="plant must be a TargetFollowerPlant"):
        VisualTrackingController(None)


def test_mpc_horizon_is_bounded(env_for):
    """Before: horizon 10000 built for ~2 s and took up to 4 s a step; the bound keeps a
    step well within the 20 ms control period (numbers in controllers/mpc.py)."""
    with pytest.raises(
        ValueError, match=rf"horizon = 10000, must be an integer >= 1 and <= {MAX_HORIZON}"
    ):
        make_controller("mpc", env_for("mpc"), horizon=10000)
    assert make_controller("mpc", env_for("mpc"), horizon=MAX_HORIZON).horizon == MAX_HORIZON
    assert MAX_HORIZON >= 50  # the benchmark's longer horizon


def _vtc_obs(X_i, tilt=0.1):
    obs = np.zeros(STATE_DIM)
    obs[IMAGE] = X_i
    obs[StateIndex.TILT] = tilt
    obs[StateIndex.TRACKING_VALID] = 1.0
    return obs


@pytest.mark.parametrize(
    "X_i",
    [
        (10.0, 5.0, 0.0),  # no width: det B_i = 0
        (10.0, 5.0, -3.0),
        (1e30, 1e30, 1e30),
        (1e30, 0.0, 10.0),
        (0.0, 0.0, 1e30),
        (1e200, -1e200, 1e200),
    ],
)
def test_vtc_stops_and_reports_where_b_i_is_singular(env_for, X_i):
    """Before: numpy.linalg.LinAlgError from the solve."""
    controller = make_controller("vtc", env_for("vtc"))
    with pytest.warns(RuntimeWarning, match="B_i is singular"):
        action, state = controller.predict(_vtc_obs(X_i))
    np.testing.assert_array_equal(action, np.zeros(3))
    assert state is None
    assert controller.last_singular.tolist() == [True]
    assert controller.singular_stops == 1 and controller.stops == 1
    # a batch: the good row is controlled, the singular one stopped, no second warning
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        actions, _ = controller.predict(np.stack([_vtc_obs((20.0, -10.0, 30.0)), _vtc_obs(X_i)]))
    assert np.any(actions[0] != 0.0)
    np.testing.assert_array_equal(actions[1], np.zeros(3))
    assert controller.last_singular.tolist() == [False, True]
    assert controller.singular_stops == 2


def test_vtc_tracking_invalid_is_no_singularity(env_for):
    controller = make_controller("vtc", env_for("vtc"))
    obs = _vtc_obs((10.0, 5.0, 0.0))
    obs[StateIndex.TRACKING_VALID] = 0.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        action, _ = controller.predict(obs)
    np.testing.assert_array_equal(action, np.zeros(3))
    assert controller.singular_stops == 0 and controller.stops == 1


@pytest.mark.parametrize("name", list(ENV_OF))
def test_bad_observations_raise_for_every_controller(env_for, name):
    env = env_for(name)
    controller = make_controller(name, env)
    n = env.unwrapped.state_space.shape[0]
    good = np.zeros(n)
    for obs, message in [
        (np.full(n, np.nan), "not finite"),
        (np.full(n, np.inf), "not finite"),
        (np.r_[good[:-1], -np.inf], "not finite"),
        (np.zeros(n + 1), "shape"),
        (np.zeros((2, n - 1)), "shape"),
        (np.zeros((1, 2, n)), "shape"),
        (np.zeros(0), "shape"),
        (None, "array of numbers"),
        ("obs", "array of numbers"),
        (np.zeros(n).astype(object), "array of numbers"),  # numbers, but objects
        ([[0.0] * n, [0.0]], "array of numbers"),
        (object(), "array of numbers"),
    ]:
        with pytest.raises(ValueError, match=message):
            controller.predict(obs)


@pytest.mark.parametrize("name", list(ENV_OF))
@pytest.mark.parametrize("scale", [1e30, 1e300])
def test_huge_finite_observations_give_a_finite_action_in_bounds(env_for, name, scale):
    env = env_for(name)
    controller = make_controller(name, env)
    n = env.unwrapped.state_space.shape[0]
    obs = scale * np.where(np.arange(n) % 2 == 0, 1.0, -1.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        action, _ = controller.predict(obs)
    assert np.all(np.isfinite(action))
    assert env.action_space.contains(action)


@pytest.mark.parametrize("key", ["env", "name"])
def test_an_option_named_like_make_controllers_arguments_is_unknown(env_for, key):
    """Before: TypeError "got multiple values for argument" (found by the fuzz suite)."""
    with pytest.raises(ValueError, match=f"unknown option\\(s\\) \\['{key}'\\]"):
        make_controller("lqr", env_for("lqr"), **{key: None})
