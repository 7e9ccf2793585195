"""Hostile outside entries, written into a test's folder as a module ``hostile`` (on the
Python path of the test and of the workers it spawns): observers and controllers that
forge the ground truth, give bad covariances, raise or exit part-way."""

from __future__ import annotations

import sys
from pathlib import Path

MODULE = "hostile"

SOURCE = '''
"""Outside entries of BallTable-v0 that misbehave."""

import sys

import numpy as np

from observer_gym.controllers import make_controller
from observer_gym.estimation import Estimate, default_pipeline


class Kf:
    """The package's kf, then ``misbehave(self, estimate, info)`` after ``after`` steps."""

    def __init__(self, env, after=0):
        self.inner, self.after = default_pipeline(env, "kf"), after

    def reset(self):
        self.inner.reset()
        self.n = 0

    def observe(self, obs, info, action):
        estimate = self.inner.observe(obs, info, action)
        self.n += 1
        if self.n > self.after:
            return self.misbehave(estimate, info)
        return estimate

    def misbehave(self, estimate, info):
        return estimate


class Forger(Kf):
    """Writes its estimate into the ground truth it is shown."""

    def misbehave(self, estimate, info):
        info["state"][:] = estimate.mean
        return estimate


class UnlockingForger(Kf):
    """Sets the shown ground truth writeable again, then writes its estimate into it."""

    def misbehave(self, estimate, info):
        state = info["state"]
        state.flags.writeable = True
        state[:] = estimate.mean
        return estimate


def forger(env):
    return Forger(env)


def unlocking_forger(env):
    return UnlockingForger(env)


class Covariance(Kf):
    """Replaces the covariance by ``kind``'s."""

    def __init__(self, env, kind, after=3):
        super().__init__(env, after)
        self.kind = kind

    def misbehave(self, estimate, info):
        P = np.array(estimate.covariance, dtype=float)
        if self.kind == "negative":
            P[0, 0] = -abs(P[0, 0])
        elif self.kind == "zero":
            P = np.zeros_like(P)
        elif self.kind == "asymmetric":
            P[0, 1] += 0.1 * np.sqrt(P[0, 0] * P[1, 1]) + 1e-3
        elif self.kind == "indefinite":
            n = len(P)
            P = np.eye(n)
            P[0, 1] = P[1, 0] = 2.0  # unit variances, correlation 2: eigenvalue -1
        return Estimate(P @ np.zeros(len(P)) + estimate.mean, P, estimate.measurement_used,
                        estimate.measurement, estimate.time_s)


def covariance(env, kind="negative", after=3):
    return Covariance(env, kind, after)


class Raises(Kf):
    def misbehave(self, estimate, info):
        raise RuntimeError("the filter diverged")


def raises_late(env, after=4):
    return Raises(env, after)


class Exits(Kf):
    def misbehave(self, estimate, info):
        sys.exit(0)


def exits_in_observe(env, after=4):
    return Exits(env, after)


def exits_in_factory(env):
    sys.exit(0)


class Lqr:
    def __init__(self, env, scale=1.0, mode="plain"):
        self.lqr = make_controller("lqr", env)
        self.scale, self.mode = scale, mode

    def reset(self):
        self.lqr.reset()

    def observe_info(self, info):
        if self.mode == "forge":
            info["state"][:] = 0.0
        elif self.mode == "forge_estimate":
            info["estimate"]["covariance"][:] = 1e6 * np.eye(len(info["estimate"]["mean"]))

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        if self.mode == "exit":
            sys.exit(0)
        if self.mode == "raise":
            raise KeyError("no such gain")
        action, _ = self.lqr.predict(obs)
        return self.scale * np.asarray(action, dtype=float), state


def controller(env, scale=1.0, mode="plain"):
    return Lqr(env, scale, mode)
'''

EXITS_ON_IMPORT = """
import sys

sys.exit(0)


def make(env):
    raise AssertionError("never reached")
"""


def write_hostile(root: Path) -> Path:
    """``root`` with the modules ``hostile`` and ``hostile_exit`` (exits when imported)."""
    root.mkdir(parents=True, exist_ok=True)
    (root / f"{MODULE}.py").write_text(SOURCE)
    (root / "hostile_exit.py").write_text(EXITS_ON_IMPORT)
    return root


def forget_hostile() -> None:
    for name in (MODULE, "hostile_exit"):
        sys.modules.pop(name, None)
