"""The post-hoc variance scale of a learned observer's network, and its fusion gate.

**Variance scale.** A network trained with the Gaussian negative log-likelihood learns
its variance on its training data; on the closed loop it drives (its own errors steering
the system), and from frames (the learned detector's errors, which it never saw in
training), its variance can be too small. The scale is one factor per output entry and
per observation mode (``"measurements"``, ``"rgb"``), fitted on validation episodes whose
seeds are disjoint from the tests' and the consistency study's
(``benchmarks/learned_variance_scale.py``): the mean of ``error^2 / variance`` per entry,
so that the scaled variance matches the squared error on average, or (``--ranges study
--estimator geometric``) the geometric mean over episodes drawn across the consistency
study's ranges of pixel noise, latency and drops of each episode's mean, so that the
NEES/dof of those conditions sits around 1 on a log scale (BallCatcher's and BallTable's
measurements scales; BallTable's rgb scale over the study's frames part's image noise and
latency instead: the command is in the report). One scale serves every condition:
none of those options is an input of the network but through the frames' ages, and the
scale does not read them. It is stored in the weight file's report (``<name>.json``, key
``"variance_scale"``, with the command that fitted it and its seeds); the observation
mode is the env's configuration, known at run time, never the truth. A report without the
key scales by 1 (the network as trained).

**Fusion gate.** ``learned-kf`` fuses the network's output as a measurement. The network
reads the last ``k`` frames, so two outputs less than ``k`` frames apart share inputs and
their errors are correlated (BallTable's: 0.77 at a lag of one frame, see
estimation/ball_table/learned_kf.py); a Kalman filter that fuses every output as independent
counts the same information up to ``k`` times and claims too little variance.
:class:`FuseEvery` passes one output in every ``n`` new frames (``n = k``: windows that
do not overlap; each observer chooses ``n`` by measurement and says why).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

__all__ = ["VARIANCE_SCALE_KEY", "FuseEvery", "variance_scale"]

VARIANCE_SCALE_KEY = "variance_scale"
OBS_MODES = ("measurements", "rgb")


def variance_scale(report: Mapping[str, Any], obs_mode: str, n_out: int) -> np.ndarray:
    """The (n_out,) factors for the network's variances in ``obs_mode`` from its
    ``report`` (ones if the report has none for that mode).

    Raises:
        ValueError: ``obs_mode`` is not one of ``"measurements"``, ``"rgb"``, or the
            report's entry is not ``n_out`` positive finite numbers.
    """
    if obs_mode not in OBS_MODES:
        raise ValueError(f"variance scale: obs_mode must be one of {OBS_MODES}, got {obs_mode!r}")
    entry = report.get(VARIANCE_SCALE_KEY, {}).get(obs_mode)
    if entry is None:
        return np.ones(n_out)
    scale = np.asarray(entry, dtype=float)
    if scale.shape != (n_out,) or not np.all(np.isfinite(scale) & (scale > 0.0)):
        raise ValueError(
            f"variance scale for {obs_mode!r} must be {n_out} positive finite numbers, "
            f"got {entry!r}; fit it again with benchmarks/learned_variance_scale.py"
        )
    return scale


class FuseEvery:
    """Passes one network output in every ``every`` new frames (the first one passes).

    Args:
        every: frames between two fused outputs (>= 1; 1 fuses every output).
    """

    def __init__(self, every: int) -> None:
        if isinstance(every, bool) or not isinstance(every, int) or every < 1:
            raise ValueError(f"fuse_every must be an integer >= 1, got {every!r}")
        self.every = every
        self.reset()

    def reset(self) -> None:
        self._since = -1  # new frames since the last fused output (-1: none fused yet)

    def new_frame(self) -> bool:
        """Count a new frame; True if its network output is to be fused."""
        if self._since < 0 or self._since + 1 >= self.every:
            self._since = 0
            return True
        self._since += 1
        return False
