"""Checking actions before they reach PyBullet (a NaN there corrupts the world for good)."""

from __future__ import annotations

import reprlib

import numpy as np
from gymnasium import spaces


def checked_action(action, space: spaces.Box) -> np.ndarray:
    """The action as a float64 array clipped to ``space``.

    Raises:
        ValueError: the action is not real numbers (complex, strings, objects, a masked
            array), has the wrong shape, or holds NaN or inf.
    """
    if isinstance(action, np.ma.MaskedArray):
        raise ValueError("action must be a plain array of real numbers, got a masked array")
    try:
        raw = np.asarray(action)
    except (TypeError, ValueError) as err:  # e.g. ragged sequences
        raise ValueError(f"action must be real numbers with shape {space.shape}: {err}") from None
    if raw.dtype.kind not in "iuf":
        raise ValueError(
            f"action must be real numbers with shape {space.shape}, got dtype {raw.dtype} "
            f"({reprlib.repr(action)})"
        )
    a = np.asarray(raw, dtype=np.float64)
    if a.shape != space.shape:
        raise ValueError(f"action must have shape {space.shape}, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"action must be finite (no NaN or inf), got {a.tolist()}")
    return np.clip(a, space.low, space.high)
