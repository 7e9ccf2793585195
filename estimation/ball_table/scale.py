"""The image scale the BallTable detector's pixel constants were set at.

They were measured on the spec's camera, 320x240 at 90 deg of horizontal field of view:
a focal length of REFERENCE_FOCAL_PX. :func:`image_scale` is a frame's focal length
relative to it, at most 1.
"""

from __future__ import annotations

import numpy as np

REFERENCE_FOCAL_PX = 160.0


def image_scale(K: np.ndarray) -> float:
    """min(1, f / REFERENCE_FOCAL_PX), f the smaller of the frame's focal lengths."""
    return min(1.0, min(float(K[0, 0]), float(K[1, 1])) / REFERENCE_FOCAL_PX)
