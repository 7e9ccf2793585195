"""How a BallTable observer drives its filter: :class:`FusedObserver` reads each step's new
frame (estimation/ball_table/frames.py) and fuses it into a
:class:`~observer_gym.estimation.latency.FilterCore` (``kf``'s two filters, ``ekf``'s one),
at its delivery or at its capture time; :class:`Fused` is a measurement on its way in,
which records the NIS its updates gave for the step's :class:`~observer_gym.estimation.
observer.Estimate`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from observer_gym.envs.ball_table import BallTableEnv
from observer_gym.estimation.ball_table.features import BallTableFeatures
from observer_gym.estimation.ball_table.frames import FrameReader
from observer_gym.estimation.ball_table.noise import BallTableNoiseRule
from observer_gym.estimation.latency import CaptureTimeFusion, TimedMeasurement
from observer_gym.estimation.observer import Estimate

__all__ = ["Fused", "FusedObserver", "history_s"]


@dataclass
class Fused:
    """A measurement as a filter core takes it, and what its last fusion gave: the sum of
    the NIS of its accepted updates and their dimensions (None, 0 when none was accepted)."""

    value: Any
    nis: float | None = None
    nis_dof: int = 0

    def clear_nis(self) -> None:
        """Before a fusion (a late measurement is fused again when a later one rewinds)."""
        self.nis, self.nis_dof = None, 0

    def add_nis(self, nis: float, dof: int) -> None:
        self.nis = nis if self.nis is None else self.nis + nis
        self.nis_dof += dof


def history_s(env: BallTableEnv) -> float:
    """How far back capture-time fusion keeps the filter's past: the declared sensor's
    (``SensorSpec.history_s``: its latest delivery and capture jitter to five standard
    deviations, and two control steps)."""
    return env.sensor_spec.history_s(env.config.dt_s)


class FusedObserver:
    """An observer whose filter is a :class:`~observer_gym.estimation.latency.FilterCore`:
    the first call (after a reset) starts the core from its measurement; each later one
    fuses the step's new frame, at its delivery (predict to the step's time, update: the
    plain drive) or, ``latency_aware``, at its capture time through
    :class:`~observer_gym.estimation.latency.CaptureTimeFusion`, which keeps
    :func:`history_s` of the filter's past to rewind to.

    The covariance it reports is the core's plus the declared calibration's offset, which
    no filter holds (the noise rule's :meth:`~observer_gym.estimation.ball_table.noise.
    BallTableNoiseRule.reported`, at the frame a subclass last gave to
    :meth:`_track_calibration`, or the one a subclass's :meth:`_reported` sets;
    ``rate_gain_per_s``: the tilt rate's g in g (u - tilt)).

    A subclass gives :meth:`_read` (the frame's raw detection and the core's measurement)
    and :meth:`_start` (the core)."""

    def __init__(
        self,
        env: BallTableEnv,
        reader: FrameReader,
        latency_aware: bool,
        noise: BallTableNoiseRule,
        rate_gain_per_s: float,
    ) -> None:
        self.reader = reader
        self.latency_aware = latency_aware
        self.history_s = history_s(env)
        self.noise = noise
        self.rate_gain_per_s = rate_gain_per_s
        self.reset()

    def reset(self) -> None:
        self.reader.reset()
        self.noise.reset()
        self._calibration: np.ndarray | None = None
        self.core: Any = None
        self.fusion: CaptureTimeFusion | None = None

    def _track_calibration(
        self, features: BallTableFeatures, K: np.ndarray, T_world_cam: np.ndarray
    ) -> None:
        """The calibration's offset at this frame's features (kept for the report)."""
        self._calibration = self.noise.calibration_cov(features, K, T_world_cam)

    def _read(self, obs: Any, frame: dict) -> tuple[Any, Fused]:
        """(the frame's raw detection, the core's measurement of it)."""
        raise NotImplementedError

    def _start(self, time_s: float, measurement: Fused | None) -> tuple[Any, bool]:
        """The core at ``time_s`` started from the first measurement (None: no frame), and
        whether the measurement was used."""
        raise NotImplementedError

    def observe(self, obs: Any, info: dict, action: np.ndarray | None) -> Estimate:
        frame, obs = self.reader.new_frame(obs, info)
        raw, measurement = self._read(obs, frame) if frame is not None else (None, None)
        time_s = float(info["time_s"])
        if self.core is None:
            self.core, used = self._start(time_s, measurement)
            if self.latency_aware:
                self.fusion = CaptureTimeFusion(self.core, True, self.history_s)
        elif self.fusion is not None:
            timed = []
            if frame is not None:
                timed.append(TimedMeasurement(frame["capture_time_s"], measurement))
            used = self.fusion.step(time_s, action, timed)
        else:
            self.core.predict_to(time_s, action)
            used = measurement is not None and self.core.update(measurement)
        nis = measurement.nis if measurement is not None else None
        dof = measurement.nis_dof if measurement is not None else 0
        covariance = self._reported(self.core.covariance())
        return Estimate(self.core.mean(), covariance, used, raw, time_s, nis, dof)

    def _reported(self, covariance: np.ndarray) -> np.ndarray:
        """The core's ``covariance`` plus the calibration's offset (see the class)."""
        return self.noise.reported(covariance, self._calibration, self.rate_gain_per_s)
