"""Observations handed out by the envs."""

from __future__ import annotations

import numpy as np


def copy_observation(obs):
    """A copy of an observation (an array, or a dict of arrays) sharing no memory with it.

    A dropped frame repeats the last delivered one; returning a copy keeps consecutive
    observations independent, so changing one in place cannot change another.
    """
    if isinstance(obs, dict):
        return {key: np.array(value, copy=True) for key, value in obs.items()}
    return np.array(obs, copy=True)
