"""BallTable's ``learned-kf`` observer: the ``learned`` network as ``kf``'s measurement
model. The network (estimation/ball_table/learned.py) replaces the detector; the filters
(estimation/ball_table/observer.py, :class:`TiltBallFilters`) stay.

Per new frame, the network reads the newest frames' detections as ``learned`` does, with
the frame's own capture time as "now" (the newest frame's age 0), so what it estimates is
the state at the capture, as a detector's measurement is. Its tilt (4:6) and ball
position (0:2) are ``kf``'s tilt and ball measurements, and the diagonal covariance it
predicts for them is their R (plus ``kf``'s frame-age term when fused at delivery). Its
velocity and rate outputs are not used: the filters make their own from the models.

Its errors are correlated: the network reads the last four frames, so consecutive
outputs share three of them; the autocorrelation of its normalised error, measured on
validation episodes (seeds 2000000-2000002, 1 px, ``python
benchmarks/learned_variance_scale.py --env BallTable-v0 --observer learned --episodes
3``), is 0.77, 0.55, 0.39, 0.34 at lags 1 to 4 frames (a first-order Gauss-Markov
error with 0.77 per frame over a floor of ~0.33 that does not decay within eight frames:
a slowly varying bias). Fusing every output as
independent made NEES/dof 4.6 on those seeds. Of the three ways to handle it (fuse only
outputs whose windows overlap less, augment the state with the Gauss-Markov error, or
Bryson-Henrikson differencing), the first is the only one that keeps ``kf``'s filters as
they are, and measured on the validation seeds (ball position RMSE x, y; median NEES/dof;
the network's variance scaled as ``learned``'s) it lands in the band: every frame 2.5,
1.7 mm, 2.23; every 2nd 2.8, 2.5 mm, 1.36; every 4th (no shared frame) 4.1, 3.8 mm,
0.77 (with the scale fitted at 1 px; the scale fitted across the consistency study's
ranges since moved the test seeds' 2 px cell from 1.54 to 1.19, docs/learned_observers.md).
:data:`FUSE_EVERY` is the smallest spacing whose NEES/dof is within [1/2, 2] on
those seeds: 2. What it costs is RMSE (every 4th frame errs by more than the network
alone, 3.6 and 3.1 mm); augmentation would keep every frame's information, but the
floor of ~0.33 is not first-order Gauss-Markov either, and is not modelled.
The network's covariance is scaled per entry by the variance scale in its report
(estimation/learned/variance_scale.py), fitted on validation episodes on ``learned``: its
own claimed about half its ball error. The scale depends on the newest frame's age, and
``learned-kf`` takes it at the fused frame's age when it is delivered (the step's time
minus its capture time), though the network itself reads that frame at its capture (age
0 in its features): the age at delivery is the one the scale was fitted against, it is
what grows with the sensor's latency (in the consistency study ``learned-kf``'s NEES/dof
grew with the latency under one constant scale, to 2.07 at 0.2 s from measurements and
3.39 from frames), and R at the capture's age would be the age-0 scale at every latency.
Like ``learned`` its network is trained on the perfect detector's measurements and knows
no calibration error: nothing of the calibration's offset is reported. From rendered
frames (``learned-kf``, obs_mode "rgb") the learned detector
(estimation/ball_table/learned_detector.py) reads each frame in the perfect detector's
place, as for ``learned``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from observer_gym.envs.ball_table import BallTableEnv
from observer_gym.estimation.ball_table.fusion import Fused
from observer_gym.estimation.ball_table.learned import LearnedObserver
from observer_gym.estimation.ball_table.observer import BallTableObserver, TiltBallDetection
from observer_gym.estimation.learned.inputs import require_frames_or_measurements
from observer_gym.estimation.learned.variance_scale import FuseEvery
from observer_gym.estimation.observer import Estimate
from observer_gym.extras import TORCH_MODULES

__all__ = ["FUSE_EVERY", "LearnedKFObserver"]

# one network output fused in every two frames: chosen on validation seeds, see above
FUSE_EVERY = 2


class LearnedKFObserver(BallTableObserver):
    """``learned-kf`` (and, with ``latency_aware=True``, fused at the capture time) for
    BallTable-v0: see the module docstring.

    Args:
        env: the (unwrapped) env, made with ``obs_mode="rgb"`` (frames through the learned
            detector) or ``"measurements"``.
        weights: the network's weight file (default: ``learned``'s shipped one; refused
            if changed).
        latency_aware: fuse each frame at its capture time, as ``kf-latency``.
        detector_weights: the learned detector's weight file, from frames (default: the
            shipped one; refused if changed).
        fuse_every: fuse the network's output of one frame in this many (default
            :data:`FUSE_EVERY`; 1 fuses every frame's).
    """

    # PyTorch runs the network: the [rl] extra (observer_gym.extras)
    NEEDS_MODULES = TORCH_MODULES

    def __init__(
        self,
        env: BallTableEnv,
        weights: str | Path | None = None,
        latency_aware: bool = False,
        detector_weights: str | Path | None = None,
        fuse_every: int = FUSE_EVERY,
    ) -> None:
        require_frames_or_measurements(env, "learned-kf of BallTable-v0")
        self.gate = FuseEvery(fuse_every)  # refuses a bad value before torch loads
        # refuses a changed weight file; from frames, loads the learned detector
        self.learned = LearnedObserver(env, weights, detector_weights)
        self._action: np.ndarray | None = None
        self._now_s = 0.0
        super().__init__(env, latency_aware=latency_aware)

    def reset(self) -> None:
        super().reset()
        self.learned.reset()
        self.gate.reset()
        self._action = None

    def observe(self, obs: Any, info: dict, action: np.ndarray | None) -> Estimate:
        self._action = action  # the network reads the last action with the frames
        self._now_s = float(info["time_s"])  # the frame's age at delivery: R's scale
        return super().observe(obs, info, action)

    def _start_calibration(self) -> None:
        """None: the network's tilt is not PnP's, so the gravity-offset states that kf
        sizes from the geometry stage's calibration sensitivity do not apply to it."""
        return None

    def _read(self, obs: Any, frame: dict):
        self.reader.mark_seen(frame)  # the image stage is the network's, not kf's
        capture_s = float(frame["capture_time_s"])
        measurement = self.learned.measurement(obs)
        features = self.learned.features
        features.new_frame(measurement, capture_s)
        if not self.gate.new_frame():  # its window overlaps the last fused one's
            return measurement, Fused(TiltBallDetection(None, None, None, None))
        age_s = self._now_s - capture_s  # the frame's age when it is delivered
        mean, cov = self.learned.predict(features.vector(capture_s, self._action), age_s)
        detection = TiltBallDetection(mean[4:6], mean[0:2], cov[4:6, 4:6], cov[0:2, 0:2])
        return measurement, Fused(detection)
