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
NEES/dof of those conditions sits around 1 on a log scale (BallCatcher's measurements
scale up to 0.05 s of the newest frame's age). One constant scale serves every
condition: none of those options is an input of the network but through the frames'
ages. BallTable's scales, from measurements and from frames (over the study's frames
part's image noise and latency), are fitted the same way but by the newest frame's age,
and BallCatcher's beyond 0.05 s of it (below): the command is in the report.
It is stored in the weight file's report (``<name>.json``, key ``"variance_scale"``, with
the command that fitted it and its seeds); the observation mode is the env's
configuration, known at run time, never the truth. A report without the key scales by 1
(the network as trained).

**Scale by the newest frame's age** (:class:`AgeVarianceScale`). Latency is an input of
the network only through the frames' ages, and past its training range its error grows
faster than the variance it learned (BallTable, trained at 0-0.05 s: median NEES/dof 4.7
at 0.2 s with one constant scale, 1.4 at 0.15 s). So the scale may depend on the age of
the newest frame the network read (the estimate's time minus that frame's capture time,
from the stamps the observer has; never the configured latency nor the truth): per
output entry, ``log(scale)`` is piecewise linear in the age between a few knots (s), and
held at the end knots' values outside them. Piecewise linear in log, because the scale
is a ratio (the band [1/3, 3] is symmetric in log) and BallTable's ratios change by
factors with the age, and not the same way for every entry (from measurements, the
ball's position 3 at 0 s, 12 at 0.05 s, 0.5 at 0.2 s; its tilt 1.8, 0.5, 13): no one
curve shape fits, a few knots do. The knots were chosen by the leave-one-out error of
the fit (RMS of log(ratio) over the validation episodes and entries): 0, 0.05, 0.1 and
0.2 s gave 0.70 from measurements and 0.62 from frames, against 0.88 and 0.85 for one
constant, 0.72 and 0.63 for 0, 0.1, 0.2 s, 0.70 and 0.65 with 0.15 s added (more knots
than episodes can hold). Clamped outside, because no episode measured what lies beyond
the knots (an age beyond the last knot is held at the last knot's scale rather than
extrapolated; before any frame arrives a network's missing-frame age is such an age).
:func:`fit_age_scale` fits it by least squares on the log of each validation episode's
mean ``error^2 / variance`` against the episode's mean newest-frame age: with one knot
that is the geometric mean over the episodes, the constant scale. ``held`` keeps the
knots up to an age at a given scale and fits the later ones: BallCatcher's constant
scale, fitted across every condition, stays where its frames are young (a free fit of
the young ages would be set by pixel noise, which is no input of the network: 4 px went
from 4.6 to 6.0), and the age adds what its latency episodes beyond 0.05 s measure. In
the report a plain
list is a constant scale; an age-dependent one is ``{"knots_age_s": [...], "scale":
[[...] per knot]}`` (positive factors, ``n_out`` per knot).

**Fusion gate.** ``learned-kf`` fuses the network's output as a measurement. The network
reads the last ``k`` frames, so two outputs less than ``k`` frames apart share inputs and
their errors are correlated (BallTable's: 0.77 at a lag of one frame, see
estimation/ball_table/learned_kf.py); a Kalman filter that fuses every output as independent
counts the same information up to ``k`` times and claims too little variance.
:class:`FuseEvery` passes one output in every ``n`` new frames (``n = k``: windows that
do not overlap; each observer chooses ``n`` by measurement and says why).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np

__all__ = [
    "VARIANCE_SCALE_KEY",
    "AgeVarianceScale",
    "FuseEvery",
    "fit_age_scale",
    "load_variance_scale",
    "parse_entry",
    "variance_scale",
]

VARIANCE_SCALE_KEY = "variance_scale"
OBS_MODES = ("measurements", "rgb")


REFIT = "fit it again with benchmarks/learned_variance_scale.py"


class AgeVarianceScale(NamedTuple):
    """A variance scale per output entry as a function of the newest frame's age (see the
    module docstring): ``log(scale)`` linear between ``knots_age_s`` (s, increasing),
    held at the end knots' values outside them; one knot is a constant scale."""

    knots_age_s: np.ndarray  # (K,) s, strictly increasing
    scale: np.ndarray  # (K, n_out): the positive factors at each knot

    @property
    def n_out(self) -> int:
        return int(self.scale.shape[1])

    @property
    def is_constant(self) -> bool:
        return len(self.knots_age_s) == 1

    def at(self, age_s: float) -> np.ndarray:
        """The (n_out,) factors at the newest frame's age ``age_s`` (s)."""
        if self.is_constant:
            return self.scale[0]
        # np.interp holds the end values outside the knots: the clamping
        log = [np.interp(age_s, self.knots_age_s, col) for col in np.log(self.scale).T]
        return np.exp(np.array(log))

    def to_entry(self) -> list[float] | dict[str, Any]:
        """The report's entry: a plain list for one knot (a constant scale), else the knots
        and the factors at each."""
        if self.is_constant:
            return self.scale[0].tolist()
        return {"knots_age_s": self.knots_age_s.tolist(), "scale": self.scale.tolist()}

    @classmethod
    def constant(cls, scale: Sequence[float] | np.ndarray) -> AgeVarianceScale:
        return cls(np.zeros(1), np.asarray(scale, dtype=float).reshape(1, -1))


def _positive_finite(value: Any, shape: tuple[int, ...], what: str) -> np.ndarray:
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        array = None
    if array is None or array.shape != shape or not np.all(np.isfinite(array) & (array > 0)):
        raise ValueError(
            f"{what} must be {' x '.join(map(str, shape))} positive finite numbers, "
            f"got {value!r}; {REFIT}"
        )
    return array


def _checked_knots(value: Any, what: str, hint: str = "") -> np.ndarray:
    try:
        knots = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        knots = np.array([np.nan])
    if (
        knots.ndim != 1
        or len(knots) == 0
        or not np.all(np.isfinite(knots) & (knots >= 0))
        or np.any(np.diff(knots) <= 0)
    ):
        raise ValueError(
            f"{what}: knots_age_s must be a non-empty list of strictly increasing ages "
            f">= 0 s, got {value!r}{hint}"
        )
    return knots


def parse_entry(entry: Any, n_out: int, what: str) -> AgeVarianceScale:
    """The scale of a report's entry: a list of ``n_out`` factors (constant), or a mapping
    with ``knots_age_s`` (increasing, finite, >= 0) and ``scale`` (one list of ``n_out``
    factors per knot).

    Raises:
        ValueError: naming ``what`` and what is wrong with the entry.
    """
    if isinstance(entry, Mapping):
        if set(entry) != {"knots_age_s", "scale"}:
            raise ValueError(
                f"{what}: an age-dependent scale has the keys 'knots_age_s' and 'scale', "
                f"got {sorted(entry)}; {REFIT}"
            )
        knots = _checked_knots(entry["knots_age_s"], what, f"; {REFIT}")
        scale = _positive_finite(entry["scale"], (len(knots), n_out), f"{what}: scale")
        return AgeVarianceScale(knots, scale)
    return AgeVarianceScale.constant(_positive_finite(entry, (n_out,), what))


def load_variance_scale(report: Mapping[str, Any], obs_mode: str, n_out: int) -> AgeVarianceScale:
    """The variance scale for ``obs_mode`` in a network's ``report`` (constant or
    age-dependent; a constant 1 if the report has none for that mode).

    Raises:
        ValueError: ``obs_mode`` is not one of ``"measurements"``, ``"rgb"``, or the
            report's entry is not a valid scale of ``n_out`` entries.
    """
    if obs_mode not in OBS_MODES:
        raise ValueError(f"variance scale: obs_mode must be one of {OBS_MODES}, got {obs_mode!r}")
    entry = report.get(VARIANCE_SCALE_KEY, {}).get(obs_mode)
    if entry is None:
        return AgeVarianceScale.constant(np.ones(n_out))
    return parse_entry(entry, n_out, f"variance scale for {obs_mode!r}")


def variance_scale(report: Mapping[str, Any], obs_mode: str, n_out: int) -> np.ndarray:
    """The (n_out,) constant factors for the network's variances in ``obs_mode`` from its
    ``report`` (ones if the report has none for that mode).

    Raises:
        ValueError: ``obs_mode`` is not one of ``"measurements"``, ``"rgb"``, the
            report's entry is not ``n_out`` positive finite numbers, or it depends on the
            age (read that with :func:`load_variance_scale`).
    """
    scale = load_variance_scale(report, obs_mode, n_out)
    if not scale.is_constant:
        raise ValueError(
            f"variance scale for {obs_mode!r} depends on the newest frame's age "
            f"(knots {scale.knots_age_s.tolist()} s): this observer reads a constant scale "
            "only; read it with load_variance_scale"
        )
    return scale.scale[0]


def fit_age_scale(
    ages_s: Sequence[float] | np.ndarray,
    ratios: Sequence[Sequence[float]] | np.ndarray,
    knots_age_s: Sequence[float] | np.ndarray,
    held: tuple[float, Sequence[float] | np.ndarray] | None = None,
) -> AgeVarianceScale:
    """Fit :class:`AgeVarianceScale` to validation episodes: ``ages_s`` (E,) each episode's
    mean newest-frame age (s), ``ratios`` (E, n_out) its mean ``error^2 / variance`` of
    the unscaled network per entry. Least squares of ``log(ratios)`` on the piecewise-linear
    basis of ``knots_age_s`` (ages outside the knots count at the end knot). One knot:
    the geometric mean over the episodes.

    ``held = (hold_to_s, scale)`` holds the knots up to ``hold_to_s`` (itself a knot) at
    the given (n_out,) factors and fits only the later ones, the held knots' part of each
    episode's log ratio taken out first: a scale fitted across every condition (such as
    BallCatcher's constant one, where pixel noise, which is no input of the network, sets
    the young ages' factors) stays as it is where the frames are young, and the age adds
    only what the latency episodes beyond ``hold_to_s`` measure.

    Raises:
        ValueError: the shapes differ, a ratio is not positive and finite, the knots are
            not increasing, a knot has no episode to fit it (the basis is rank-deficient:
            fewer knots, or episodes at those ages), or ``held`` is not a knot with
            ``n_out`` positive factors and a later knot to fit.
    """
    ages = np.asarray(ages_s, dtype=float)
    ratio = np.asarray(ratios, dtype=float)
    if not np.all(np.isfinite(ratio) & (ratio > 0)):
        raise ValueError("fit: every ratio error^2 / variance must be positive and finite")
    log_ratio = np.log(ratio)
    knots = _checked_knots(knots_age_s, "fit")
    if ages.ndim != 1 or log_ratio.ndim != 2 or len(ages) != len(log_ratio) or not len(ages):
        raise ValueError(
            f"fit: ages_s must be (E,) and ratios (E, n_out) with E >= 1, got "
            f"{ages.shape} and {log_ratio.shape}"
        )
    if not np.all(np.isfinite(ages)):
        raise ValueError(f"fit: ages_s must be finite, got {ages.tolist()}")
    # the hat functions of the knots at each episode's age (np.interp clamps at the ends)
    basis = np.stack([np.interp(ages, knots, row) for row in np.eye(len(knots))], axis=1)
    fixed = np.zeros(len(knots), dtype=bool)
    log_scale = np.zeros((len(knots), log_ratio.shape[1]))
    if held is not None:
        hold_to_s, held_scale = held
        fixed = knots <= hold_to_s
        if not np.any(np.isclose(knots, hold_to_s)) or fixed.all():
            raise ValueError(
                f"fit: hold_to_s must be one of the knots {knots.tolist()} s but the last, "
                f"got {hold_to_s!r}"
            )
        n_out = log_ratio.shape[1]
        log_scale[fixed] = np.log(_positive_finite(held_scale, (n_out,), "fit: held scale"))
        # the held knots' part of each episode's log ratio, taken out before the fit
        log_ratio = log_ratio - basis[:, fixed] @ log_scale[fixed]
    free = basis[:, ~fixed]
    if np.linalg.matrix_rank(free) < free.shape[1]:
        raise ValueError(
            f"fit: the episodes' ages {np.round(ages, 4).tolist()} s do not determine a scale "
            f"at every knot {knots[~fixed].tolist()} s: use fewer knots or episodes at those ages"
        )
    log_scale[~fixed], *_ = np.linalg.lstsq(free, log_ratio, rcond=None)
    return AgeVarianceScale(knots, np.exp(log_scale))


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
