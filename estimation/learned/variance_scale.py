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
NEES/dof of those conditions sits around 1 on a log scale. A constant scale serves
every condition alike: none of those options is an input of the network but through
the frames' ages. BallTable's scales, from measurements and from frames (over the
study's frames part's image noise and latency), and BallCatcher's from frames are fitted
the same way but by the newest frame's age; BallCatcher's from measurements by the age
and by two numbers of the declared sensor (below): the command is in the report.
It is stored in the weight file's report (``<name>.json``, key ``"variance_scale"``, with
the command that fitted it and its seeds); the observation mode is the env's
configuration, known at run time, never the truth. A report without the key scales by 1
(the network as trained).

**Scale by the newest frame's age** (:class:`VarianceScale`). Latency is an input of
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
:func:`fit_variance_scale` fits it by least squares on the log of each validation episode's
mean ``error^2 / variance`` against the episode's mean newest-frame age: with one knot
that is the geometric mean over the episodes, the constant scale. ``held`` keeps the
knots up to an age at a given scale and fits the later ones (BallCatcher's frames scale:
1 where its frames are young, the age adding what its latency episodes beyond 0.05 s
measure). In the report a plain list is a constant scale; an age-dependent one is
``{"knots_age_s": [...], "scale": [[...] per knot]}`` (positive factors, ``n_out`` per
knot).

**Terms by the declared sensor** (:class:`DeclaredTerm`). BallCatcher's network is
trained to 2 px of pixel noise, 10 % drops and no calibration error, and past them its
error grows faster than the variance it learned: one scale across the study's 0-4 px
left its median NEES/dof at 0.39 at 0 px and 4.58 at 4 px, a spread of twelve that no
constant can put inside the band's nine, and a scale fitted freely by the age alone was
set by the pixel noise at young ages. None of these options is an input of the network,
but each is a number of the declared sensor (:class:`~observer_gym.envs.sensor.SensorSpec`:
the data sheet the env publishes as ``env.sensor_spec``, from which ``kf`` takes its R
and its calibration consider parameters; never the realised draws). So the scale may
read them as inputs of the variance alone (the network's mean does not see them): per
declared number, ``log(scale)`` gains a term piecewise linear between its knots, 0 at
the first knot, held at the end knots' values outside them, fitted by
:func:`fit_variance_scale` jointly with the age on episodes that vary each option in
turn (``--by-declared NAME=KNOTS``; BallCatcher reads the pixel noise, the drop
probability and the rotation and focal calibration errors). Additive in log: each option
multiplies the variance independently of the others. The study varies one option at a
time, so a combination is that assumption's, not a measurement's (at 0 px with 0.2 s of
latency, where the 0 px term shrinks a variance the latency's error dominates, BallCatcher
reads 2.77 on the tests' throws, inside the band but near its edge). A network retrained
with the declared noise as an input of its mean was also measured: its NEES came in, but
it lost a third of its catches at 1 px (docs/results/consistency.md); the terms leave
the shipped network's mean as it is. In the report: ``"declared": {NAME: {"knots":
[...], "scale": [[...] per knot]}}`` beside the age's knots.

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
from dataclasses import fields
from typing import Any, NamedTuple

import numpy as np

from observer_gym.envs.sensor import SensorSpec

__all__ = [
    "VARIANCE_SCALE_KEY",
    "DeclaredTerm",
    "FuseEvery",
    "VarianceScale",
    "checked_r_inflation",
    "declared_numbers",
    "fit_variance_scale",
    "load_variance_scale",
    "parse_entry",
    "variance_scale",
]

VARIANCE_SCALE_KEY = "variance_scale"
OBS_MODES = ("measurements", "rgb")


# the declared sensor's numbers a scale may read (SensorSpec's fields but the image size)
SENSOR_FIELDS = frozenset(f.name for f in fields(SensorSpec)) - {"image_size_px"}
REFIT = "fit it again with benchmarks/learned_variance_scale.py"


class DeclaredTerm(NamedTuple):
    """One term of a :class:`VarianceScale` by a number of the declared sensor
    (:class:`~observer_gym.envs.sensor.SensorSpec`): ``log`` of the factors linear between
    ``knots`` (in that number's unit, increasing), held at the end knots' values outside
    them, and 1 at the first knot (the age scale is the scale there)."""

    name: str  # a SensorSpec field, e.g. "measurement_noise_std_px"
    knots: np.ndarray  # (M,) strictly increasing, >= 0
    scale: np.ndarray  # (M, n_out): the positive factors at each knot, the first all 1


class VarianceScale(NamedTuple):
    """A variance scale per output entry as a function of the newest frame's age and,
    optionally, numbers of the declared sensor (see the module docstring): ``log(scale)``
    is linear between ``knots_age_s`` (s, increasing), held at the end knots' values
    outside them, plus one :class:`DeclaredTerm` per declared number; one age knot and no
    declared term is a constant scale."""

    knots_age_s: np.ndarray  # (K,) s, strictly increasing
    scale: np.ndarray  # (K, n_out): the positive factors at each age knot
    declared: tuple[DeclaredTerm, ...] = ()

    @property
    def n_out(self) -> int:
        return int(self.scale.shape[1])

    @property
    def declared_names(self) -> tuple[str, ...]:
        return tuple(term.name for term in self.declared)

    @property
    def is_constant(self) -> bool:
        return len(self.knots_age_s) == 1 and not self.declared

    def at(self, age_s: float, declared: Mapping[str, float] | None = None) -> np.ndarray:
        """The (n_out,) factors at the newest frame's age ``age_s`` (s) and, for a scale
        with declared terms, the declared sensor's numbers ``declared`` (name -> value;
        ValueError if one is missing)."""
        log = _interp_log(age_s, self.knots_age_s, self.scale)
        for term in self.declared:
            value = None if declared is None else declared.get(term.name)
            if value is None or not np.isfinite(value):
                raise ValueError(
                    f"this variance scale depends on the declared {term.name} (knots "
                    f"{term.knots.tolist()}): give it in declared, got {declared!r}"
                )
            log = log + _interp_log(value, term.knots, term.scale)
        return np.exp(log)

    def to_entry(self) -> list[float] | dict[str, Any]:
        """The report's entry: a plain list for a constant scale, else the knots and the
        factors at each."""
        if self.is_constant:
            return self.scale[0].tolist()
        entry: dict[str, Any] = {
            "knots_age_s": self.knots_age_s.tolist(),
            "scale": self.scale.tolist(),
        }
        if self.declared:
            entry["declared"] = {
                t.name: {"knots": t.knots.tolist(), "scale": t.scale.tolist()}
                for t in self.declared
            }
        return entry

    @classmethod
    def constant(cls, scale: Sequence[float] | np.ndarray) -> VarianceScale:
        return cls(np.zeros(1), np.asarray(scale, dtype=float).reshape(1, -1))


def _interp_log(x: float, knots: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """(n_out,) log factors at ``x``, linear between the knots, held outside them."""
    if len(knots) == 1:
        return np.log(scale[0])
    # np.interp holds the end values outside the knots: the clamping
    return np.array([np.interp(x, knots, column) for column in np.log(scale).T])


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


def _checked_knots(
    value: Any, what: str, hint: str = "", name: str = "knots_age_s", noun: str = "ages >= 0 s"
) -> np.ndarray:
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
            f"{what}: {name} must be a non-empty list of strictly increasing {noun}, "
            f"got {value!r}{hint}"
        )
    return knots


AGE_KEYS = {"knots_age_s", "scale"}


def parse_entry(entry: Any, n_out: int, what: str) -> VarianceScale:
    """The scale of a report's entry: a list of ``n_out`` factors (constant), or a mapping
    with ``knots_age_s`` (increasing, finite, >= 0) and ``scale`` (one list of ``n_out``
    factors per knot), and optionally ``declared``: per declared sensor number (a
    :class:`~observer_gym.envs.sensor.SensorSpec` field) its ``knots`` (increasing, finite,
    >= 0) and ``scale`` (one list of ``n_out`` factors per knot, the first all 1).

    Raises:
        ValueError: naming ``what`` and what is wrong with the entry.
    """
    if not isinstance(entry, Mapping):
        return VarianceScale.constant(_positive_finite(entry, (n_out,), what))
    if set(entry) not in (AGE_KEYS, AGE_KEYS | {"declared"}):
        raise ValueError(
            f"{what}: a scale by age has the keys 'knots_age_s' and 'scale', and "
            f"optionally 'declared', got {sorted(entry)}; {REFIT}"
        )
    knots = _checked_knots(entry["knots_age_s"], what, f"; {REFIT}")
    scale = _positive_finite(entry["scale"], (len(knots), n_out), f"{what}: scale")
    terms = []
    declared = entry.get("declared", {})
    if not isinstance(declared, Mapping):
        raise ValueError(f"{what}: 'declared' must map sensor numbers to terms; {REFIT}")
    for name, term in declared.items():
        if name not in SENSOR_FIELDS:
            raise ValueError(
                f"{what}: declared {name!r} is not a number of the declared sensor, one of "
                f"{sorted(SENSOR_FIELDS)}; {REFIT}"
            )
        if not isinstance(term, Mapping) or set(term) != {"knots", "scale"}:
            raise ValueError(f"{what}: declared {name!r} needs 'knots' and 'scale'; {REFIT}")
        term_knots = _checked_knots(
            term["knots"], what, f"; {REFIT}", f"{name} knots", "values >= 0"
        )
        term_scale = _positive_finite(
            term["scale"], (len(term_knots), n_out), f"{what}: declared {name!r} scale"
        )
        if not np.allclose(term_scale[0], 1.0):
            raise ValueError(
                f"{what}: declared {name!r} scale at its first knot must be 1 (the age "
                f"scale is the scale there), got {term_scale[0].tolist()}; {REFIT}"
            )
        terms.append(DeclaredTerm(name, term_knots, term_scale))
    return VarianceScale(knots, scale, tuple(terms))


def declared_numbers(spec: Any, scale: VarianceScale) -> dict[str, float]:
    """The declared sensor's numbers ``scale`` reads (name -> value) from ``spec``, a
    :class:`~observer_gym.envs.sensor.SensorSpec`: the data sheet, as ``kf``'s R reads
    it, never the realised draws."""
    return {name: float(getattr(spec, name)) for name in scale.declared_names}


def load_variance_scale(report: Mapping[str, Any], obs_mode: str, n_out: int) -> VarianceScale:
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
        return VarianceScale.constant(np.ones(n_out))
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
            f"variance scale for {obs_mode!r} depends on the newest frame's age or the "
            f"declared sensor ({scale.to_entry()}): this observer reads a constant scale "
            "only; read it with load_variance_scale"
        )
    return scale.scale[0]


def _hats(x: np.ndarray, knots: np.ndarray) -> np.ndarray:
    """(E, K): the knots' hat functions at each x (np.interp clamps at the end knots)."""
    return np.stack([np.interp(x, knots, row) for row in np.eye(len(knots))], axis=1)


def fit_variance_scale(
    ages_s: Sequence[float] | np.ndarray,
    ratios: Sequence[Sequence[float]] | np.ndarray,
    knots_age_s: Sequence[float] | np.ndarray,
    held: tuple[float, Sequence[float] | np.ndarray] | None = None,
    declared: Mapping[str, tuple[Sequence[float] | np.ndarray, Sequence[float]]] | None = None,
) -> VarianceScale:
    """Fit :class:`VarianceScale` to validation episodes: ``ages_s`` (E,) each episode's
    mean newest-frame age (s), ``ratios`` (E, n_out) its mean ``error^2 / variance`` of
    the unscaled network per entry. Least squares of ``log(ratios)`` on the piecewise-linear
    basis of ``knots_age_s`` (ages outside the knots count at the end knot). One knot:
    the geometric mean over the episodes.

    ``declared`` maps a declared sensor number's name to ((E,) each episode's value, its
    knots): the basis has those knots' hat functions too, but the first's (the term is 0
    there: an age term and a declared term would otherwise trade a constant), fitted
    jointly with the age.

    ``held = (hold_to_s, scale)`` holds the age knots up to ``hold_to_s`` (itself a knot)
    at the given (n_out,) factors and fits only the later ones, the held knots' part of
    each episode's log ratio taken out first: a scale fitted across every condition stays
    as it is where the frames are young, and the age adds only what the latency episodes
    beyond ``hold_to_s`` measure.

    Raises:
        ValueError: the shapes differ, a ratio is not positive and finite, the knots are
            not increasing, a knot has no episode to fit it (the basis is rank-deficient:
            fewer knots, or episodes at those ages or values), or ``held`` is not a knot
            with ``n_out`` positive factors and a later knot to fit.
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
    n_out = log_ratio.shape[1]
    basis = _hats(ages, knots)
    fixed = np.zeros(len(knots), dtype=bool)
    log_scale = np.zeros((len(knots), n_out))
    if held is not None:
        hold_to_s, held_scale = held
        fixed = knots <= hold_to_s
        if not np.any(np.isclose(knots, hold_to_s)) or fixed.all():
            raise ValueError(
                f"fit: hold_to_s must be one of the knots {knots.tolist()} s but the last, "
                f"got {hold_to_s!r}"
            )
        log_scale[fixed] = np.log(_positive_finite(held_scale, (n_out,), "fit: held scale"))
        # the held knots' part of each episode's log ratio, taken out before the fit
        log_ratio = log_ratio - basis[:, fixed] @ log_scale[fixed]
    columns = [basis[:, ~fixed]]
    term_knots = {}
    for name, (values, value_knots) in (declared or {}).items():
        term_knots[name] = _checked_knots(value_knots, "fit", "", f"{name} knots", "values >= 0")
        x = np.asarray(values, dtype=float)
        if x.shape != ages.shape or not np.all(np.isfinite(x)):
            raise ValueError(f"fit: {name} must be (E,) finite values like ages_s, got {x}")
        columns.append(_hats(x, term_knots[name])[:, 1:])  # 0 at the first knot
    free = np.concatenate(columns, axis=1)
    if np.linalg.matrix_rank(free) < free.shape[1]:
        raise ValueError(
            f"fit: the episodes' ages {np.round(ages, 4).tolist()} s (and declared values) "
            f"do not determine a scale at every knot (age {knots[~fixed].tolist()} s, "
            f"{ {n: k.tolist() for n, k in term_knots.items()} }): use fewer knots or "
            "episodes at those values"
        )
    solution, *_ = np.linalg.lstsq(free, log_ratio, rcond=None)
    at = int((~fixed).sum())
    log_scale[~fixed] = solution[:at]
    terms = []
    for name, k in term_knots.items():
        log_term = np.concatenate([np.zeros((1, n_out)), solution[at : at + len(k) - 1]])
        terms.append(DeclaredTerm(name, k, np.exp(log_term)))
        at += len(k) - 1
    return VarianceScale(knots, np.exp(log_scale), tuple(terms))


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


def checked_r_inflation(value: Any, owner: str) -> float:
    """``value`` as ``learned-kf``'s R inflation (R = ``value`` x the network's variance):
    a finite number >= 1, else ValueError naming ``owner``. Fusing one output in ``n``
    still leaves the errors of outputs ``n`` frames apart correlated; a factor above 1
    lets each fused output count for less (each observer chooses it by measurement)."""
    if isinstance(value, bool) or not (isinstance(value, int | float) and np.isfinite(value)):
        raise ValueError(f"{owner}: r_inflation must be a number >= 1, got {value!r}")
    if value < 1.0:
        raise ValueError(f"{owner}: r_inflation must be >= 1, got {value!r}")
    return float(value)
