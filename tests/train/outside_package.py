"""A package from outside observer-gym, written into a test's folder: observers and
controllers as a researcher would bring them, good and bad, and (optionally) the
dist-info that an install writes, with entry points."""

from __future__ import annotations

import sys
import textwrap
from pathlib import Path

PACKAGE = "obslab"
VERSION = "0.3.1"

FILTERS = '''
"""Observers of BallTable-v0 from outside observer-gym."""

import numpy as np

from observer_gym.estimation import Estimate, default_pipeline

BALL = slice(0, 2)
VELOCITY = slice(2, 4)


class AlphaBeta:
    """The raw detection's ball position through an alpha-beta filter; the rest raw."""

    def __init__(self, env, alpha=0.5, beta=0.1):
        self.raw = default_pipeline(env, "raw")
        self.alpha, self.beta, self.dt_s = alpha, beta, env.dt_s

    def reset(self):
        self.raw.reset()
        self.x = None

    def observe(self, obs, info, action):
        detection = self.raw.observe(obs, info, action)
        if self.x is None:
            self.x = detection.mean.copy()
        else:
            x = self.x.copy()
            x[BALL] += self.dt_s * x[VELOCITY]
            if detection.measurement_used:
                residual = detection.mean[BALL] - x[BALL]
                x[BALL] += self.alpha * residual
                x[VELOCITY] += self.beta / self.dt_s * residual
            x[4:] = detection.mean[4:]
            self.x = x
        return Estimate(
            self.x.copy(), detection.covariance, detection.measurement_used,
            detection.measurement, detection.time_s,
        )


def make_observer(env, alpha=0.5, beta=0.1):
    return AlphaBeta(env, alpha, beta)


class Delegate:
    """The package's own kf, passed through: must give exactly kf's numbers."""

    def __init__(self, env):
        self.inner = default_pipeline(env, "kf")

    def reset(self):
        self.inner.reset()

    def observe(self, obs, info, action):
        return self.inner.observe(obs, info, action)


def make_delegate(env):
    return Delegate(env)


def wrong_layout(env):
    class Short:
        def reset(self):
            pass

        def observe(self, obs, info, action):
            return Estimate(np.zeros(3), np.eye(3), False, None, 0.0)

    return Short()


def not_an_estimate(env):
    class Plain:
        def reset(self):
            pass

        def observe(self, obs, info, action):
            return np.zeros(8)

    return Plain()


def no_observe(env):
    return object()


def raises(env):
    raise RuntimeError("calibration file missing")


def nan_after(env, step=40):
    inner = make_observer(env)

    class Late:
        def reset(self):
            inner.reset()
            self.n = 0

        def observe(self, obs, info, action):
            self.n += 1
            estimate = inner.observe(obs, info, action)
            if self.n > step:
                estimate.mean[0] = np.nan
            return estimate

    return Late()


NOT_CALLABLE = 3
'''

CONTROL = '''
"""Controllers of BallTable-v0 from outside observer-gym."""

import numpy as np

from observer_gym.controllers import make_controller


class Scaled:
    """The package's LQR with its action scaled by ``gain``."""

    def __init__(self, env, gain=1.0):
        self.lqr = make_controller("lqr", env)
        self.gain = gain
        self.resets = 0

    def reset(self):
        self.resets += 1

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        action, _ = self.lqr.predict(obs)
        return self.gain * np.asarray(action), state


def make_controller_(env, gain=1.0):
    return Scaled(env, gain)


def wrong_shape(env):
    class Three:
        def predict(self, obs, state=None, episode_start=None, deterministic=True):
            return np.zeros(3), state

    return Three()


def nan_action(env):
    class Nan:
        def predict(self, obs, state=None, episode_start=None, deterministic=True):
            return np.full(2, np.nan), state

    return Nan()


def not_a_tuple(env):
    class Bare:
        def predict(self, obs, state=None, episode_start=None, deterministic=True):
            return np.zeros(2)

    return Bare()
'''

BROKEN = """
raise ImportError("obslab.broken needs a GPU driver")
"""


def write_package(root: Path, entry_points: bool = False) -> Path:
    """Write the package ``obslab`` under ``root`` (and, with ``entry_points``, the
    dist-info an install writes: version and the entry-point groups); returns ``root``."""
    package = root / PACKAGE
    package.mkdir(parents=True, exist_ok=True)
    (package / "__init__.py").write_text(f'__version__ = "{VERSION}"\n')
    (package / "filters.py").write_text(textwrap.dedent(FILTERS))
    (package / "control.py").write_text(textwrap.dedent(CONTROL))
    (package / "broken.py").write_text(textwrap.dedent(BROKEN))
    if entry_points:
        info = root / f"{PACKAGE}-{VERSION}.dist-info"
        info.mkdir(exist_ok=True)
        (info / "METADATA").write_text(
            f"Metadata-Version: 2.1\nName: {PACKAGE}\nVersion: {VERSION}\n"
        )
        (info / "top_level.txt").write_text(f"{PACKAGE}\n")
        (info / "RECORD").write_text(
            "".join(f"{PACKAGE}/{name},,\n" for name in ("__init__.py", "filters.py", "control.py"))
        )
        (info / "entry_points.txt").write_text(
            "[observer_gym.observers]\n"
            f"alpha-beta = {PACKAGE}.filters:make_observer\n"
            "[observer_gym.controllers]\n"
            f"scaled-lqr = {PACKAGE}.control:make_controller_\n"
        )
    return root


def forget_package() -> None:
    """Drop the package's modules from this process (each test writes its own copy)."""
    for name in [m for m in sys.modules if m == PACKAGE or m.startswith(PACKAGE + ".")]:
        del sys.modules[name]
