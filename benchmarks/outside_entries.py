"""Outside entries for benchmarks/bench_sweep.py: the package's own kf and LQR passed
through, so that an outside cell does exactly a built-in cell's work and the difference
in time is what the outside path costs."""

from observer_gym.controllers import make_controller
from observer_gym.estimation import default_pipeline


def kf_delegate(env):
    """observer-gym's kf pipeline, as an outside observer factory would return it."""
    return default_pipeline(env, "kf")


def lqr_delegate(env):
    """observer-gym's LQR, as an outside controller factory would return it."""
    return make_controller("lqr", env)
