"""What an outside entry is shown and what it may return: read-only copies in, checked
estimates out.

An outside observer's pipeline (:class:`CheckedPipeline`) and an outside controller
(:class:`~observer_gym.train.core.controller_entries.CheckedController`) are shown
each step's observation and info as :func:`read_only` copies: arrays that are copies
with ``writeable=False``, mappings as read-only mappings. Writing into one is refused in
one line naming the entry; an entry that sets an array writeable again changes only its
own copy, never what the episode records. Whatever an entry raises (any exception, and
``sys.exit``) ends the episode with one line naming the entry and the method, never a
traceback. An observer's covariance must be one the NEES can use
(:func:`checked_covariance`).
"""

from __future__ import annotations

import copy
import dataclasses
import types
from collections.abc import Mapping
from typing import Any

import numpy as np

from observer_gym.estimation.observer import Estimate, checked_estimate
from observer_gym.train.core import entries

# |P_ij - P_ji| <= SYMMETRY_RTOL * sqrt(P_ii P_jj): a covariance symmetric to the
# rounding of a filter's update (a Joseph-form update keeps ~1e-12), not to a wrong sign.
SYMMETRY_RTOL = 1e-6
# The smallest eigenvalue of the correlation matrix D^-1/2 P D^-1/2 accepted: that of
# the NEES's rank test (observer_gym.train.reports.consistency.RANK_TOL), so an accepted
# covariance keeps every degree of freedom.
CORRELATION_MIN_EIGENVALUE = 1e-9


def read_only(value: Any) -> Any:
    """A copy of ``value`` that an entry cannot write through: arrays copied with
    ``writeable=False``, mappings as read-only mappings (``types.MappingProxyType``) of
    such copies, lists and tuples as tuples, anything else deep-copied."""
    if isinstance(value, np.ndarray):
        shown = value.copy()
        shown.flags.writeable = False
        return shown
    if isinstance(value, Mapping):
        return types.MappingProxyType({key: read_only(item) for key, item in value.items()})
    if isinstance(value, (list, tuple)) and not hasattr(value, "_fields"):
        return tuple(read_only(item) for item in value)
    if value is None or isinstance(value, (bool, int, float, str, bytes, np.generic)):
        return value
    return copy.deepcopy(value)


def entry_fault(where: str, call: str, exc: BaseException) -> ValueError:
    """The one-line ValueError for an entry whose ``call`` raised ``exc`` (an exception or
    ``sys.exit``); a write into a read-only view says so."""
    text = str(exc)
    if isinstance(exc, SystemExit):
        text = f"sys.exit({exc.code!r}) ends only the entry, not the command"
    elif isinstance(exc, (ValueError, TypeError)) and (
        "read-only" in text or "does not support item assignment" in text
    ):
        text = f"{text}: an entry is shown read-only copies of the observation and info"
    # one line, escapes shown as text: an entry's message reaches a terminal
    return ValueError(f"{where}: {call} raised {type(exc).__name__}: {entries.printable(text)}")


def checked_covariance(covariance: np.ndarray, who: str, time_s: float) -> None:
    """ValueError naming observer ``who`` unless ``covariance`` is one the NEES uses with
    all its degrees of freedom: positive variances, symmetric within
    :data:`SYMMETRY_RTOL` of sqrt(P_ii P_jj), and positive definite (the correlation
    matrix's eigenvalues above :data:`CORRELATION_MIN_EIGENVALUE`)."""
    P = np.asarray(covariance, dtype=float)
    where = f"observer {who!r}: the covariance at t = {time_s} s"
    variances = np.diag(P)
    bad = np.flatnonzero(~(variances > 0.0))
    if bad.size:
        raise ValueError(
            f"{where} has the variance {variances[bad[0]]!r} at [{bad[0]}, {bad[0]}]; "
            "every variance must be > 0"
        )
    deviations = np.sqrt(variances)
    scale = np.outer(deviations, deviations)  # the square roots first: no overflow
    with np.errstate(over="ignore", under="ignore"):  # an inf here is refused just below
        asymmetry = np.abs(P / scale - P.T / scale)
    if not asymmetry.max() <= SYMMETRY_RTOL:
        i, j = np.unravel_index(int(np.argmax(asymmetry)), P.shape)
        raise ValueError(
            f"{where} is not symmetric: P[{i}, {j}] = {P[i, j]!r}, P[{j}, {i}] = {P[j, i]!r} "
            f"(allowed: |P_ij - P_ji| <= {SYMMETRY_RTOL} sqrt(P_ii P_jj))"
        )
    correlation = 0.5 * (P / scale + P.T / scale)
    try:
        smallest = float(np.linalg.eigvalsh(correlation).min())
    except np.linalg.LinAlgError:  # no eigenvalues found: not a usable covariance either
        smallest = float("nan")
    if not smallest > CORRELATION_MIN_EIGENVALUE:
        raise ValueError(
            f"{where} is not positive definite: its correlation matrix has the eigenvalue "
            f"{smallest:.3g} (allowed: > {CORRELATION_MIN_EIGENVALUE})"
        )


class CheckedPipeline:
    """An outside observer's pipeline as :class:`~observer_gym.estimation.VisionObserver`
    drives it: shown read-only copies, its faults one line, its covariance checked."""

    def __init__(self, pipeline: Any, plugin: entries.Plugin, state_dim: int) -> None:
        self.pipeline = pipeline
        self.name = plugin.name
        self._state_dim = state_dim
        self._where = f"observer {plugin.name!r}"

    def reset(self) -> None:
        try:
            self.pipeline.reset()
        except (Exception, SystemExit) as exc:
            raise entry_fault(self._where, "reset()", exc) from None

    def observe(self, obs: Any, info: Mapping[str, Any], action: Any) -> Estimate:
        try:
            estimate = self.pipeline.observe(
                read_only(obs), read_only(info), None if action is None else read_only(action)
            )
        except (Exception, SystemExit) as exc:
            raise entry_fault(self._where, "observe()", exc) from None
        checked_estimate(estimate, self._state_dim, self.name)
        checked_covariance(estimate.covariance, self.name, estimate.time_s)
        # the estimate's arrays as the episode records them: copies the entry cannot reach
        return dataclasses.replace(
            estimate,
            mean=np.array(estimate.mean, dtype=float),
            covariance=np.array(estimate.covariance, dtype=float),
        )
