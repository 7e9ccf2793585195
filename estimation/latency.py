"""Fusing each measurement at its capture time: the latency-aware drive of a filter.

A camera with latency L delivers at time t a frame captured at t_c <= t - L. A filter that
fuses it at t (``kf``) treats an old picture as a new one. :class:`CaptureTimeFusion`
instead (``kf-latency``):

1. keeps, for every step time t_j of the last ``history_s`` seconds, a snapshot of the
   filter after that step, the input held over the interval that ends at t_j, and the
   measurements fused in that interval with their capture times;
2. when measurements arrive, rewinds to the newest snapshot at or before the earliest
   capture time among them (or the oldest one kept), and replays forward in time order:
   predict to each capture time with the input held then, update with that measurement
   (the new ones and the ones fused earlier in the replayed span alike), predict to each
   step time and snapshot it;
3. so the estimate at step k is x(t_k | all measurements captured up to t_k), predicted
   to t_k: the time the next action is applied.

With zero latency every capture time is the step time, nothing is rewound, and the
sequence of filter calls is exactly that of fusing at delivery (predict to t_k, update):
the two drives give the same numbers bit for bit (tests/estimation/test_latency.py).
Measurements delivered out of capture order (latency jitter) are fused in capture order.
One captured earlier than the kept history is fused at the oldest snapshot kept.

Written here rather than taken from a library: the filter libraries (filterpy, pykalman)
offer no out-of-sequence measurement handling; rewind-and-replay is the exact solution for
any filter whose state can be snapshotted.

A system's filter plugs in through :class:`FilterCore`.
"""

from __future__ import annotations

import bisect
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Generic, Protocol, TypeVar

__all__ = ["CaptureTimeFusion", "FilterCore", "TimedMeasurement"]

# Times closer than this are the same instant (capture and step times are tick multiples
# computed by different sums).
SAME_TIME_S = 1e-9

# What a core holds over a step interval: the env's applied action (an array), or what
# the system's core derives from it (target_follower's HeldInput)
A = TypeVar("A")
A_contra = TypeVar("A_contra", contravariant=True)


class FilterCore(Protocol[A_contra]):
    """A system's filter as :class:`CaptureTimeFusion` drives it.

    ``predict_to(time_s, action)`` propagates the estimate from its current time to
    ``time_s`` (>= it) with ``action`` (the env's applied action, or what the system makes
    of it; None before the first step) held over the interval; ``update(measurement)``
    fuses one measurement taken at the current time and returns whether it was used;
    ``snapshot()`` returns an object from which ``restore`` puts the filter back exactly
    (time included).
    ``predict_to`` the current time must leave the filter unchanged.
    """

    time_s: float

    def predict_to(self, time_s: float, action: A_contra | None) -> None: ...

    def update(self, measurement: Any) -> bool: ...

    def snapshot(self) -> Any: ...

    def restore(self, snapshot: Any) -> None: ...


@dataclass(frozen=True)
class TimedMeasurement:
    """A measurement (whatever the system's filter updates with) and when it was captured."""

    capture_time_s: float
    measurement: Any


@dataclass
class _Step(Generic[A]):
    time_s: float
    action: A | None  # held over the interval that ends at time_s
    measurements: list[TimedMeasurement] = field(default_factory=list)  # captured in it
    snapshot: Any = None  # the filter after predicting to time_s and fusing the above


class CaptureTimeFusion(Generic[A]):
    """Drives a :class:`FilterCore` so that each measurement is fused at its capture time
    (``latency_aware=True``) or at its delivery (``False``: the plain drive, the same calls
    a filter without this class makes). See the module docstring.

    Args:
        core: the system's filter, already at its start time.
        latency_aware: fuse at capture time (True) or at delivery (False).
        history_s: how far back a late measurement can rewind (>= the largest latency plus
            jitter the sensor can have; older captures are fused at the oldest step kept).
    """

    def __init__(self, core: FilterCore[A], latency_aware: bool, history_s: float = 1.0) -> None:
        if not history_s > 0.0:
            raise ValueError(f"CaptureTimeFusion: history_s = {history_s!r}, must be > 0")
        self.core = core
        self.latency_aware = latency_aware
        self.history_s = float(history_s)
        self._steps: list[_Step[A]] = [_Step(core.time_s, None, [], core.snapshot())]
        self.rewinds = 0  # how many steps rewound the filter (late measurements)

    def step(
        self, time_s: float, action: A | None, measurements: Sequence[TimedMeasurement]
    ) -> bool:
        """Advance to step time ``time_s`` with ``action`` held since the last step and fuse
        ``measurements`` (delivered now). Returns whether any measurement was used."""
        measurements = sorted(measurements, key=lambda m: m.capture_time_s)
        if not self.latency_aware or all(
            m.capture_time_s >= time_s - SAME_TIME_S for m in measurements
        ):
            return self._advance(time_s, action, measurements)
        return self._rewind_and_replay(time_s, action, measurements)

    def _advance(self, time_s, action, measurements) -> bool:
        core = self.core
        core.predict_to(time_s, action)
        used = False
        for m in measurements:
            used |= bool(core.update(m.measurement))
        self._remember(_Step(time_s, action, list(measurements), core.snapshot()))
        return used

    def _rewind_and_replay(self, time_s, action, measurements) -> bool:
        steps = self._steps
        earliest = measurements[0].capture_time_s
        times = [s.time_s for s in steps]
        # The newest kept step at or before the earliest capture (else the oldest kept).
        start = max(0, bisect.bisect_right(times, earliest + SAME_TIME_S) - 1)
        self.rewinds += 1
        self.core.restore(steps[start].snapshot)
        oldest_s = steps[start].time_s
        # Replay the kept steps after `start`, then the new one, each with its measurements
        # (new ones go to the interval that holds their capture time).
        replay = [_Step(s.time_s, s.action, list(s.measurements)) for s in steps[start + 1 :]]
        replay.append(_Step(time_s, action, []))
        for m in measurements:
            capture_s = max(m.capture_time_s, oldest_s)
            i = next(i for i, s in enumerate(replay) if capture_s <= s.time_s + SAME_TIME_S)
            replay[i].measurements.append(TimedMeasurement(capture_s, m.measurement))
        del steps[start + 1 :]
        new = {id(m.measurement) for m in measurements}
        used = False
        core = self.core
        for s in replay:
            for m in sorted(s.measurements, key=lambda m: m.capture_time_s):
                # predict to the capture (a no-op when it is the current time), fuse there
                core.predict_to(min(m.capture_time_s, s.time_s), s.action)
                used_now = bool(core.update(m.measurement))
                used |= used_now and id(m.measurement) in new
            core.predict_to(s.time_s, s.action)
            s.snapshot = core.snapshot()
            steps.append(s)
        self._forget()
        return used

    def _remember(self, step: _Step[A]) -> None:
        self._steps.append(step)
        self._forget()

    def _forget(self) -> None:
        oldest_kept_s = self._steps[-1].time_s - self.history_s
        drop = 0
        while drop < len(self._steps) - 1 and self._steps[drop + 1].time_s < oldest_kept_s:
            drop += 1
        if drop:
            del self._steps[:drop]
