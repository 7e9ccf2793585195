"""``r_scale``, the factor on an observer's measurement noise R that sensitivity studies
(and the consistency tests' deliberately mis-scaled R) set; 1 is the noise rule's R."""

from __future__ import annotations

import math

__all__ = ["checked_r_scale"]


def checked_r_scale(r_scale: float) -> float:
    """``r_scale`` as a float; ValueError unless finite and > 0."""
    try:
        value = float(r_scale)
    except (TypeError, ValueError):
        raise ValueError(f"r_scale = {r_scale!r}: must be a finite number > 0") from None
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"r_scale = {r_scale!r}: must be a finite number > 0")
    return value
