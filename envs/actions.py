"""Checking actions before they reach PyBullet (a NaN there corrupts the world for good)."""

from __future__ import annotations

import numpy as np
from gymnasium import spaces


def checked_action(action, space: spaces.Box) -> np.ndarray:
    """The action as a float64 array clipped to ``space``.

    Raises:
        ValueError: the action is not numeric, has the wrong shape, or holds NaN or inf.
    """
    try:
        a = np.asarray(action, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise ValueError(f"action must be numeric with shape {space.shape}: {err}") from None
    if a.shape != space.shape:
        raise ValueError(f"action must have shape {space.shape}, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"action must be finite (no NaN or inf), got {a.tolist()}")
    return np.clip(a, space.low, space.high)
