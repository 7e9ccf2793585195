"""Checking actions before they reach PyBullet (a NaN there corrupts the world for good)."""

from __future__ import annotations

import reprlib

import numpy as np
from gymnasium import spaces


def box_bounds(space: spaces.Box) -> tuple[np.ndarray, np.ndarray]:
    """``space``'s bounds as float64 arrays: clipping a float64 action to them gives what
    clipping to the float32 bounds gives (every float32 is a float64), without a cast per
    call."""
    return np.asarray(space.low, dtype=np.float64), np.asarray(space.high, dtype=np.float64)


def checked_action(
    action, space: spaces.Box, bounds: tuple[np.ndarray, np.ndarray] | None = None
) -> np.ndarray:
    """The action as a float64 array clipped to ``space`` (a new array).

    Args:
        bounds: ``box_bounds(space)``, when the caller keeps them.

    Raises:
        ValueError: the action is not real numbers (complex, strings, objects, a masked
            array), has the wrong shape, or holds NaN or inf.
    """
    if type(action) is np.ndarray:  # the usual case: a plain array (never a masked one)
        raw = action
    else:
        if isinstance(action, np.ma.MaskedArray):
            raise ValueError("action must be a plain array of real numbers, got a masked array")
        try:
            raw = np.asarray(action)
        except (TypeError, ValueError) as err:  # e.g. ragged sequences
            raise ValueError(
                f"action must be real numbers with shape {space.shape}: {err}"
            ) from None
    if raw.dtype.kind not in "iuf":
        raise ValueError(
            f"action must be real numbers with shape {space.shape}, got dtype {raw.dtype} "
            f"({reprlib.repr(action)})"
        )
    a = np.asarray(raw, dtype=np.float64)
    if a.shape != space.shape:
        raise ValueError(f"action must have shape {space.shape}, got shape {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"action must be finite (no NaN or inf), got {a.tolist()}")
    low, high = box_bounds(space) if bounds is None else bounds
    # np.clip's value, without its dispatch (NaN and inf were refused above).
    return np.minimum(np.maximum(a, low), high)
