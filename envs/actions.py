"""Checking actions before they reach PyBullet (a NaN there corrupts the world for good)."""

from __future__ import annotations

import math
import reprlib

import numpy as np
from gymnasium import spaces


class BoxBounds:
    """A Box's bounds as float64 arrays and as lists of floats, for :func:`checked_action`
    (every float32 is a float64, so clipping to them is clipping to the Box's bounds)."""

    def __init__(self, space: spaces.Box) -> None:
        self.space = space
        self.low = np.asarray(space.low, dtype=np.float64)
        self.high = np.asarray(space.high, dtype=np.float64)
        self.pairs = list(zip(self.low.tolist(), self.high.tolist(), strict=True))


def checked_action(action, space: spaces.Box, bounds: BoxBounds | None = None) -> np.ndarray:
    """The action as a float64 array clipped to ``space`` (a new array).

    Args:
        bounds: ``BoxBounds(space)``, when the caller keeps them.

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
    if raw.shape != space.shape:
        raise ValueError(f"action must have shape {space.shape}, got shape {raw.shape}")
    if bounds is None:
        bounds = BoxBounds(space)
    if raw.ndim == 1:
        # In floats, as NumPy's cast, isfinite and clip give them (clip: x if x > low else
        # low, then that if < high else high): no ufunc calls, which cost most of a
        # step's checks when a render has just evicted them from the caches.
        values = np.asarray(raw, dtype=np.float64).tolist()
        clipped = []
        for x, (low, high) in zip(values, bounds.pairs, strict=True):
            if not math.isfinite(x):
                raise ValueError(f"action must be finite (no NaN or inf), got {values}")
            x = x if x > low else low
            clipped.append(x if x < high else high)
        return np.array(clipped)
    a = np.asarray(raw, dtype=np.float64)
    if not np.isfinite(a).all():
        raise ValueError(f"action must be finite (no NaN or inf), got {a.tolist()}")
    return np.minimum(np.maximum(a, bounds.low), bounds.high)  # np.clip's values
