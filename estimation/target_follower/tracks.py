"""Which detections a TargetFollower filter believes: a chi-square gate on the innovation,
a detection after a gap confirmed by the next frame, and a restart after a run of
rejections that agree with each other.

A false detection (another object, a frame of something else, noise) looks to the filter
like a measurement: one far from its prediction is caught by a gate, one inside it is
not, and the gate of a track predicted blind for a while is wide. :class:`TrackPair`
keeps the *main* track (the filter whose estimate is reported) and at most one
*candidate*:

- the gate: a detection is inside a track's gate when its normalised innovation squared
  d^T S^-1 d (S = H P H^T + R, the track's own) is below the chi-square quantile
  ``gate_probability`` of its dimension;
- *in lock* (the main track used the previous frame's detection), a detection inside its
  gate is used at once;
- otherwise (after a frame without a detection, a dropped frame, a rejected detection, or
  with no track) a detection starts a candidate: the main track updated with it if it is
  inside the main track's gate (a *branch*), else a new track started at it; the main
  track meanwhile predicts on, its covariance growing as the model says;
- the candidate is fed the following frames' detections through its own gate. A branch,
  or a new track when there is no main track, becomes the main track after
  ``confirm_updates`` of them; a new track beside a main track replaces it (a *switch*)
  after ``restart_updates`` of them: a run of ``restart_updates + 1`` rejected detections
  that agree with each other is the target found elsewhere. A frame without a detection
  ends the candidate; a detection outside its gate starts the next one.

So a single false detection is never used, however wide the gate: scattered false
detections (noise) do not agree with each other from frame to frame. A burst of another
object's consistent detections is followed after ``restart_updates + 1`` frames, and the
target again ``restart_updates + 1`` frames after the burst (or ``confirm_updates + 1``
if the track was lost meanwhile). A detection after a gap costs one frame's delay: it is
used, with the next, when the next confirms it.

``gate_probability`` None is no gate (the spec's procedure): every detection is used, a
track starts at the first.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, NamedTuple, TypeVar

import numpy as np

from observer_gym.estimation.filters import KalmanFilter, UpdateResult
from observer_gym.estimation.gating import ChiSquareGate, nis

__all__ = ["Measured", "TrackPair", "TrackRule"]


@dataclass(frozen=True)
class TrackRule:
    """The gate, the confirmation and the restart of :class:`TrackPair` (module
    docstring)."""

    gate_probability: float | None = None
    confirm_updates: int = 0
    restart_updates: int = 0

    def __post_init__(self) -> None:
        p = self.gate_probability
        if p is None:
            if self.confirm_updates or self.restart_updates:
                raise ValueError("confirm_updates and restart_updates need a gate_probability")
            return
        if not 0.0 < p < 1.0:
            raise ValueError(f"gate_probability = {p!r}: None or in (0, 1)")
        if not 1 <= self.confirm_updates <= self.restart_updates:
            raise ValueError(
                f"confirm_updates = {self.confirm_updates!r}, restart_updates = "
                f"{self.restart_updates!r}: need 1 <= confirm_updates <= restart_updates"
            )


class Measured(NamedTuple):
    """What one detection did: ``event`` is "update" (the main track used it), "start"
    (a new track became the main track, none before), "confirm" (a branch became the main
    track), "switch" (a new track replaced the main track) or "candidate" (only a
    candidate used it); ``update`` the main track's :class:`UpdateResult` with it (None
    for "candidate")."""

    event: str
    update: UpdateResult | None

    @property
    def used(self) -> bool:
        """Whether the main track's estimate now contains the detection."""
        return self.event != "candidate"


# The tracks' filter class (a KalmanFilter, or a subclass such as the EKF)
F = TypeVar("F", bound=KalmanFilter)
# start(z) -> a new filter at the detection (None: it cannot start there)
Start = Callable[[np.ndarray], F | None]
# innovation(filter, z) -> (d, S) with the filter's R, or None when it cannot be formed
Innovation = Callable[[F, np.ndarray], tuple[np.ndarray, np.ndarray] | None]
# update(filter, z, is_main) -> the filter's update with z (no gate)
Update = Callable[[F, np.ndarray, bool], UpdateResult]


class TrackPair(Generic[F]):
    """The main track and the candidate of one target (module docstring); their filters
    are ``F``s (what ``start`` returns)."""

    def __init__(self, rule: TrackRule) -> None:
        self.rule = rule
        self._gate = None if rule.gate_probability is None else ChiSquareGate(rule.gate_probability)
        self.reset()

    def reset(self) -> None:
        self.main: F | None = None
        self.locked = False  # the main track used the previous frame's detection
        self.candidate: F | None = None
        self.candidate_is_branch = False
        self.candidate_updates = 0
        self.switches = 0  # new tracks that replaced a main track
        self.rejected = 0  # detections outside the main track's gate

    def filters(self) -> tuple[F, ...]:
        """The tracks there are (main first), for the caller's predict."""
        return tuple(f for f in (self.main, self.candidate) if f is not None)

    @staticmethod
    def _inside(gate: ChiSquareGate, f: F, z: np.ndarray, innovation: Innovation[F]) -> bool:
        formed = innovation(f, z)
        if formed is None:
            return False
        d, S = formed
        return nis(S, d) <= gate.threshold(d.shape[0])  # d^T S^-1 d <= chi2 quantile

    def miss(self) -> None:
        """A frame without a detection (or a frame dropped): out of lock, no candidate."""
        self.locked = False
        self.candidate, self.candidate_updates = None, 0

    def measure(
        self, z: np.ndarray, start: Start[F], innovation: Innovation[F], update: Update[F]
    ) -> Measured:
        """Use the detection ``z`` (see the module docstring)."""
        main = self.main
        gate = self._gate
        if gate is None:  # the spec: start at the first detection, use every one
            if main is None:
                self.main = start(z)
                return Measured("start" if self.main is not None else "candidate", None)
            return Measured("update", update(main, z, True))
        in_main_gate = main is not None and self._inside(gate, main, z, innovation)
        if main is not None and in_main_gate and self.locked:
            self.candidate, self.candidate_updates = None, 0
            return Measured("update", update(main, z, True))
        if main is not None and not in_main_gate:
            self.rejected += 1
        self.locked = False
        candidate = self.candidate
        if candidate is not None and self._inside(gate, candidate, z, innovation):
            result = update(candidate, z, False)
            self.candidate_updates += 1
            branch = self.candidate_is_branch
            needed = self.rule.confirm_updates
            if not branch and main is not None:
                needed = self.rule.restart_updates
            if self.candidate_updates >= needed:
                event = "confirm" if branch else ("start" if main is None else "switch")
                self.switches += event == "switch"
                self.main, self.locked = candidate, True
                self.candidate, self.candidate_updates = None, 0
                return Measured(event, result)
            return Measured("candidate", None)
        # a new candidate: the main track with z (a branch), or a new track at z
        if main is not None and in_main_gate:
            candidate = type(main)(main.x, main.P)
            update(candidate, z, False)
        else:
            candidate = start(z)
        self.candidate, self.candidate_is_branch = candidate, in_main_gate
        self.candidate_updates = 0
        return Measured("candidate", None)

    def lose_main(self) -> None:
        """The main track is lost (unreliable); a candidate runs on, as a new track (it
        becomes the main track after ``confirm_updates`` more detections)."""
        self.main, self.locked = None, False
        self.candidate_is_branch = False

    def snapshot(self) -> tuple:
        """The tracks' state (their x and P, which the filters assign afresh each step)."""
        main, candidate = (None if f is None else (f.x, f.P) for f in (self.main, self.candidate))
        flags = (self.locked, self.candidate_is_branch, self.candidate_updates)
        return (main, candidate, *flags, self.switches, self.rejected)

    def restore(self, snapshot: tuple, make: Callable[[np.ndarray, np.ndarray], F]) -> None:
        """Back to ``snapshot``; ``make(x, P)`` builds a filter where one is missing."""
        main, candidate, *rest = snapshot
        self.main = self._restored(self.main, main, make)
        self.candidate = self._restored(self.candidate, candidate, make)
        (
            self.locked,
            self.candidate_is_branch,
            self.candidate_updates,
            self.switches,
            self.rejected,
        ) = rest

    @staticmethod
    def _restored(
        f: F | None,
        state: tuple[np.ndarray, np.ndarray] | None,
        make: Callable[[np.ndarray, np.ndarray], F],
    ) -> F | None:
        if state is None:
            return None
        if f is None:
            return make(*state)
        f.x, f.P = state
        return f
