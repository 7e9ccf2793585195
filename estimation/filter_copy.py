"""An independent copy of a Kalman filter, for filters that are put back to an earlier
point: capture-time fusion (estimation/latency.py) snapshots a filter after every step and
restores a copy when a late measurement rewinds it.

The copy has the same estimate, counters, pending R12 effect and converged-gain state, so
it steps on exactly as the original would; later steps of either leave the other as it
is. x and P are shared until a step replaces them (no step writes into them); the gate
(stateless) and the scratch buffers (used within a call only) are shared too.
"""

from __future__ import annotations

import copy
from typing import TypeVar

from observer_gym.estimation.filters import KalmanFilter

__all__ = ["copy_filter"]

Filter = TypeVar("Filter", bound=KalmanFilter)


def copy_filter(kf: Filter) -> Filter:
    """An independent copy of ``kf`` (a :class:`KalmanFilter` or a subclass, such as the
    EKF): see the module docstring."""
    twin = copy.copy(kf)
    converged = kf._converged  # the converged-gain path's state changes step by step
    if converged is not None:
        twin._converged = copy.copy(converged)
    return twin
