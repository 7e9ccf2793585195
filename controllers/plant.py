"""What the generic LQR, MPC and PID design from: the plant protocols a system's
``controllers/<system>/plant.py`` provides, and the two records they hold.

A plant is one env step of a system as a discrete linear model,

    x_{k+1} = A x_k + B u_k,

whose state x is a slice of the env's "state" observation (``state_slice``: the true state
or an observer's estimate of it) and whose input u is the env's action itself, within
``action_bounds``. The protocols say what each design reads:

- :class:`LinearPlant` (LQR): ``dt_s``, ``obs_dim``, ``state_slice``, ``action_bounds``,
  ``matrices()`` -> (A, B), ``weights()`` -> the default (Q, R);
- :class:`ConstrainedPlant` (MPC): a :class:`LinearPlant` with ``constraints()`` -> its
  default :class:`StageBound` rows;
- :class:`AxesPlant` (PID): ``dt_s``, ``obs_dim``, ``action_bounds`` and ``axes()`` -> the
  :class:`DoubleIntegratorAxes` a PID per axis drives.

Any object with these members is a plant (a frozen dataclass per system, as
``BallTablePlant``); nothing here knows a system. :func:`check_plant` is the check every
design runs first.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Generic, NamedTuple, Protocol, runtime_checkable

import numpy as np

__all__ = [
    "AxesPlant",
    "ConstrainedPlant",
    "DoubleIntegratorAxes",
    "LinearPlant",
    "StageBound",
    "check_plant",
]


class StageBound(NamedTuple):
    """Rows of an MPC constraint, kept at every step k = 0..N-1 of the horizon:

        |state_rows x_{k+s} + input_rows u_k| <= limit      (row by row)

    with s = 1 when ``next_state`` (the bound holds on the states x_1..x_N the plan
    reaches) and s = 0 otherwise (on the state the input u_k is applied in). An input
    bound has zero ``state_rows``; a state bound zero ``input_rows``."""

    name: str  # for messages
    state_rows: np.ndarray  # (r, n)
    input_rows: np.ndarray  # (r, m)
    limit: np.ndarray  # (r,), finite and >= 0, in the rows' units
    next_state: bool = False


class DoubleIntegratorAxes(NamedTuple):
    """What a PID per axis drives: k axes, each a double integrator p' = v, v' = a, with
    the acceleration a = accel_per_input u (k, k) (the input's lag left out). The axes'
    positions are ``obs[positions]`` and their velocities ``obs[velocities]`` (k each).
    The PID's anti-windup takes max |accel_per_input| as every axis's gain: exact when
    each axis is driven by one input with a gain of the same magnitude (BallTable's
    signed axis swap)."""

    positions: slice
    velocities: slice
    accel_per_input: np.ndarray  # (k, k), invertible; (axis units / s^2) per input unit


@runtime_checkable
class LinearPlant(Protocol):
    """An env step as x_{k+1} = A x_k + B u_k (module docstring): what the LQR reads."""

    @property
    def dt_s(self) -> float: ...  # the env's step, the model's sample time

    @property
    def obs_dim(self) -> int: ...  # length of the env's "state" observation

    @property
    def state_slice(self) -> slice: ...  # x = obs[state_slice] (n entries)

    @property
    def action_bounds(self) -> tuple[np.ndarray, np.ndarray]: ...  # (low, high), (m,) each

    def matrices(self) -> tuple[np.ndarray, np.ndarray]: ...  # (A (n, n), B (n, m))

    def weights(self) -> tuple[np.ndarray, np.ndarray]: ...  # default (Q (n, n), R (m, m))


@runtime_checkable
class ConstrainedPlant(LinearPlant, Protocol):
    """A :class:`LinearPlant` with the MPC's default constraints."""

    def constraints(self) -> Sequence[StageBound]: ...


@runtime_checkable
class AxesPlant(Protocol):
    """What the PID reads: the step, the observation's length, the action bounds and the
    axes (:class:`DoubleIntegratorAxes`)."""

    @property
    def dt_s(self) -> float: ...

    @property
    def obs_dim(self) -> int: ...

    @property
    def action_bounds(self) -> tuple[np.ndarray, np.ndarray]: ...

    def axes(self) -> DoubleIntegratorAxes: ...


def check_plant(owner: str, plant: object, protocol: type) -> None:
    """ValueError unless ``plant`` has every member of ``protocol`` (a system's plant, e.g.
    ``BallTablePlant.from_env(env)``; or use ``make_controller``)."""
    if not isinstance(plant, protocol):
        members = sorted(
            name
            for cls in protocol.__mro__
            if cls is not object and cls is not Protocol and cls is not Generic
            for name in vars(cls)
            if not name.startswith("_")
        )
        article = "an" if protocol.__name__[0] in "AEIOU" else "a"
        raise ValueError(
            f"{owner}: plant must be {article} {protocol.__name__} (a system's plant, e.g. "
            f"BallTablePlant.from_env(env), with {', '.join(members)}), got "
            f"{type(plant).__name__}"
        )
