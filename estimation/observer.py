"""The observer wrapper: camera frames in, state estimates out.

``VisionObserver(env)`` wraps an env made with ``obs_mode="rgb"`` or ``"measurements"``.
Its observation is the estimate of the env's ground-truth state, with exactly the layout
of ``obs_mode="state"`` (``env.unwrapped.state_space``), so a controller or policy runs
unchanged on the oracle state or on the estimate. ``info["estimate"]`` carries the mean,
the covariance, whether a measurement was used this step, and the raw measurement.

What turns frames into estimates is a *pipeline* (detector + filters) chosen for the env
by :func:`default_pipeline` from the ``OBSERVERS`` of the env's system
(``observer_gym.estimation.<system>``), by name with ``observer=``; pass ``pipeline=`` to
use another.
"""

from __future__ import annotations

import importlib
import reprlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Protocol, cast

import gymnasium as gym
import numpy as np

from observer_gym.envs import System, system_of


@dataclass(frozen=True)
class Estimate:
    """One step's state estimate, in the env's state layout."""

    mean: np.ndarray  # (n,)
    covariance: np.ndarray  # (n, n)
    measurement_used: bool  # a new measurement updated the estimate this step
    measurement: Any  # the raw detection (None when no new frame arrived)
    time_s: float
    # The normalised innovation squared d^T S^-1 d of this step's measurement update
    # (the sum over the updates when several measurements were fused, with their
    # dimensions summed in ``nis_dof``); None when nothing was fused or the observer
    # has no innovation covariance.
    nis: float | None = None
    nis_dof: int = 0

    def as_info(self) -> dict[str, Any]:
        return {
            "mean": self.mean.copy(),
            "covariance": self.covariance.copy(),
            "measurement_used": self.measurement_used,
            "measurement": self.measurement,
            "time_s": self.time_s,
            "nis": self.nis,
            "nis_dof": self.nis_dof,
        }


class ObserverPipeline(Protocol):
    """Detector + filters for one env. ``observe`` is called after every reset and step
    with what the env returned and the action the env applied to get there
    (``info["applied_action"]``); None after a reset."""

    def reset(self) -> None: ...

    def observe(self, obs: Any, info: dict, action: np.ndarray | None) -> Estimate: ...


# Builds a pipeline for a system's (unwrapped) env: factory(env, **options).
PipelineFactory = Callable[..., ObserverPipeline]

# What each observer name means on every system that has it: one line for
# 'observer-gym list' and the docs.
OBSERVER_ROLES = {
    "kf": "detector + Kalman filter, each frame fused when it is delivered",
    "kf-latency": "detector + Kalman filter, each frame fused at its capture time and "
    "predicted to now (latency-aware)",
    "kf-at-delivery": "detector + Kalman filter, each frame fused when it is delivered as if "
    "captured then (no latency handling)",
    "stkf": "detector + self-tuning Kalman filter (R adapted online)",
    "stkf-latency": "detector + self-tuning Kalman filter, latency-aware",
    "ekf": "one extended Kalman filter on the image features' pixels",
    "raw": "the detector alone: the newest detection held, rates by finite differences",
    "oracle-visible": "the true state while the camera sees it, predicted otherwise",
    "learned": "a network trained on the simulator's truth: the newest frames' detections "
    "(from frames: a learned detector's) to the estimate and its covariance (no filter)",
    "learned-kf": "the learned network as the Kalman filter's measurement model (it "
    "replaces the detector, the filter stays)",
    "selfcal": "the pixel EKF estimating each camera's calibration error with the state",
    "endpoint": "selfcal with a landmark of known position (the robot's tool) in the cameras "
    "that see it: the target relative to the tool, nearly free of each camera's error",
}


def observers_of_system(system: System) -> Mapping[str, PipelineFactory]:
    """The observers of ``system``: the ``OBSERVERS`` of its package
    ``observer_gym.estimation.<system>`` (observer name -> pipeline factory; the first is
    the default)."""
    return importlib.import_module(system.module("estimation")).OBSERVERS


def env_options_of(system: System, observer: str | None) -> dict[str, Any]:
    """The env options ``system``'s observer ``observer`` needs to run: its package's
    ``ENV_OPTIONS`` (observer name -> options, e.g. BallCatcher's ``endpoint`` reads the
    hole's pixels, ``hole_measurements=True``); {} for the others."""
    module = importlib.import_module(system.module("estimation"))
    return dict(getattr(module, "ENV_OPTIONS", {}).get(observer, {}))


def observers_of(env: gym.Env) -> Mapping[str, PipelineFactory]:
    """The observers of ``env``'s system (see :func:`observers_of_system`)."""
    return observers_of_system(system_of(env))


def modules_needed(system: System, observer: str | None) -> tuple[str, ...]:
    """The modules beyond the core install that ``system``'s observer ``observer`` (None:
    its first) needs: its pipeline's ``NEEDS_MODULES`` (the learned observers': PyTorch,
    the ``[rl]`` extra, :mod:`observer_gym.extras`); () for the others and unknown names."""
    observers = observers_of_system(system)
    name = next(iter(observers)) if observer is None else observer
    return tuple(getattr(observers.get(name), "NEEDS_MODULES", ()))


def default_pipeline(env: gym.Env, observer: str | None = None, **options: Any) -> ObserverPipeline:
    """The pipeline of the observer ``observer`` of ``env``'s system (default: its
    first), built on the unwrapped env with ``options``. ValueError for an env of no known
    system or a name the system does not have, listing its observers."""
    observers = observers_of(env)
    name = next(iter(observers)) if observer is None else observer
    if name not in observers:
        raise ValueError(
            f"unknown observer {name!r} for {system_of(env).short_id}; allowed: "
            f"{', '.join(observers)}"
        )
    return observers[name](env.unwrapped, **options)


# Beyond this a measured pixel is no detection, as NaN is: far outside any image, and its
# squares overflow the filters' arithmetic.
MAX_PIXEL_PX = 1e6


def checked_measurement_array(owner: str, name: str, value: Any, shape: tuple) -> np.ndarray:
    """A measurement's entry ``name`` as a float array of ``shape``; NaN and inf are kept (a
    pipeline takes them as no detection). ValueError naming ``owner``, the entry and what is
    allowed for anything but real numbers (bools too) of that shape."""

    def error() -> ValueError:  # built on failure only: repr of an array is ~100 us
        return ValueError(
            f"{owner}: measurement {name} must be real numbers of shape {tuple(shape)}, got "
            f"{reprlib.repr(value)}"
        )

    if value is None or isinstance(value, np.ma.MaskedArray):
        raise error()
    try:
        raw = np.asarray(value)
    except (TypeError, ValueError):  # ragged sequences
        raise error() from None
    if raw.dtype.kind not in "biuf" or raw.shape != tuple(shape):
        raise error()
    return raw.astype(np.float64)


def checked_measurement(owner: str, obs: Any, space: gym.spaces.Dict) -> dict[str, np.ndarray]:
    """A measurements-mode observation checked against the env's Dict ``space``: every key
    of ``space`` with real numbers of its shape (see :func:`checked_measurement_array`), as
    float arrays; ValueError naming ``owner`` and what is wrong otherwise."""
    if not isinstance(obs, Mapping):
        raise ValueError(
            f"{owner}: the measurement must be a dict with keys {list(space.spaces)}, got "
            f"{type(obs).__name__}: {reprlib.repr(obs)}"
        )
    return {
        key: checked_measurement_array(owner, key, obs.get(key), cast(tuple, sub.shape))
        for key, sub in space.spaces.items()
    }


class VisionObserver(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Replace an env's camera observation by the state estimate of an observer.

    Args:
        env: an observer-gym env made with ``obs_mode="rgb"`` or ``"measurements"``.
        pipeline: the detector + filters to use; default :func:`default_pipeline`.
        observer: the name of one of the system's observers (default: its first);
            not with ``pipeline``.
        name: how error messages name a given ``pipeline`` (default: its class name).
        **options: passed to the observer's pipeline (not with ``pipeline``).

    Every estimate is checked against the env's state layout: ``observe`` must return an
    :class:`Estimate` whose mean (n,) and covariance (n, n) are finite, else ValueError
    naming the observer and what is wrong.

    Example:
        >>> import gymnasium as gym
        >>> import numpy as np
        >>> from observer_gym.estimation import VisionObserver
        >>> env = VisionObserver(gym.make("observer_gym/BallTable-v0"), observer="kf")
        >>> estimate, info = env.reset(seed=0)
        >>> for _ in range(50):  # one second of frames with the table level
        ...     estimate, reward, terminated, truncated, info = env.step(np.zeros(2, np.float32))
        >>> estimate.shape == env.unwrapped.state_space.shape  # the true state's layout
        True
        >>> error_m = np.abs(estimate[:2] - info["state"][:2]).max()  # ball x, y on the table
        >>> bool(error_m < 1e-3)
        True
        >>> info["estimate"]["covariance"].shape
        (8, 8)
        >>> env.close()
    """

    def __init__(
        self,
        env: gym.Env,
        pipeline: ObserverPipeline | None = None,
        observer: str | None = None,
        name: str | None = None,
        **options: Any,
    ):
        # Recorded so that gymnasium can re-create the wrapped env from its spec (a given
        # pipeline instance would then be shared; the default one is built afresh).
        gym.utils.RecordConstructorArgs.__init__(
            self, pipeline=pipeline, observer=observer, name=name, **options
        )
        gym.Wrapper.__init__(self, env)
        base: Any = env.unwrapped  # an observer-gym env, checked below
        obs_mode = getattr(getattr(base, "config", None), "obs_mode", None)
        if obs_mode not in ("rgb", "measurements"):
            raise ValueError(
                f"VisionObserver needs an env made with obs_mode='rgb' or 'measurements', "
                f"got obs_mode={obs_mode!r}"
            )
        if pipeline is not None and (options or observer is not None):
            given = sorted(options) + (["observer"] if observer is not None else [])
            raise ValueError(f"options {given} apply to the default pipeline only")
        if pipeline is None:
            pipeline = default_pipeline(env, observer, **options)
        self.pipeline = pipeline
        self.name = name or observer or type(pipeline).__name__
        self.observation_space = base.state_space

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        self.pipeline.reset()
        return self._estimate(obs, info, None)

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        # What the env applied, in its own units: a wrapper between this one and the env
        # (RescaleAction, ...) may have changed the action this wrapper was given.
        applied = info.get("applied_action")
        if applied is None:
            raise ValueError(
                "VisionObserver needs info['applied_action'] from the env's step (every "
                "observer-gym env gives it): the action the env applied"
            )
        estimate_obs, info = self._estimate(obs, info, np.asarray(applied, dtype=np.float64))
        return estimate_obs, reward, terminated, truncated, info

    def _estimate(self, obs, info: dict, action):
        space = cast(gym.spaces.Box, self.observation_space)  # the env's state_space
        estimate = checked_estimate(
            self.pipeline.observe(obs, info, action), space.shape[0], self.name
        )
        info = {**info, "estimate": estimate.as_info()}
        mean = np.clip(estimate.mean, space.low, space.high).astype(space.dtype)
        return mean, info


def checked_estimate(estimate: Any, n: int, who: str) -> Estimate:
    """``estimate`` if it is an :class:`Estimate` with a finite mean of shape (n,) and a
    finite covariance of shape (n, n); ValueError naming observer ``who`` otherwise."""
    if not isinstance(estimate, Estimate):
        raise ValueError(
            f"observer {who!r}: observe() must return an observer_gym.estimation.Estimate, "
            f"got {type(estimate).__name__}"
        )
    mean, covariance = np.asarray(estimate.mean), np.asarray(estimate.covariance)
    if mean.shape != (n,) or covariance.shape != (n, n):
        raise ValueError(
            f"observer {who!r}: the estimate must have the env's state layout, a mean of "
            f"shape ({n},) and a covariance of shape ({n}, {n}); got {mean.shape} and "
            f"{covariance.shape}"
        )
    if mean.dtype.kind not in "biuf" or covariance.dtype.kind not in "biuf":
        raise ValueError(
            f"observer {who!r}: the estimate must be real numbers, got dtypes {mean.dtype} "
            f"and {covariance.dtype}"
        )
    if not (np.isfinite(mean).all() and np.isfinite(covariance).all()):
        raise ValueError(
            f"observer {who!r}: the estimate is not finite at t = {estimate.time_s} s "
            f"(mean {reprlib.repr(mean.tolist())})"
        )
    return estimate


def checked_rgb_frame(image: Any, size_px: tuple[int, int], who: str) -> np.ndarray:
    """``image`` if it is a uint8 RGB frame of ``size_px`` = (W, H), i.e. shape (H, W, 3);
    ValueError naming ``who`` wanted it, the expected and the given shape and dtype."""
    expected = (int(size_px[1]), int(size_px[0]), 3)
    if not isinstance(image, np.ndarray) or image.dtype != np.uint8 or image.shape != expected:
        shape = getattr(image, "shape", None)
        dtype = getattr(image, "dtype", type(image).__name__)
        raise ValueError(
            f"{who}: the frame must be an RGB image of shape {expected} and dtype uint8, "
            f"got shape {shape} and dtype {dtype}"
        )
    return image
