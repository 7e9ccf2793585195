"""BallTable's ``learned`` observer: a network trained on the simulator's truth maps the
newest frames' detections to the state estimate and its covariance (no PnP, no filter).

**Features** (:class:`LearnedFeatures`, 58 numbers per step): the newest
:data:`HISTORY_FRAMES` frames received, each as the perfect detector reports it (the red
top's 4 corners and the ball's centre and semi-major axis in pixels, 11 numbers; a part
not detected, or a pixel beyond :data:`~observer_gym.estimation.observer.MAX_PIXEL_PX`,
is zeros with its ``detected`` flag 0), its two ``detected`` flags and its age (now minus
its capture time, s), newest first; before four frames have arrived the missing ones are
zeros with age :data:`MISSING_AGE_S`; and the last action (commanded tilt, rad). The ages
carry latency and drops; the history carries the rates.

**Network**: :class:`~observer_gym.estimation.learned.network.GaussianMLP` (2 x 128
tanh), trained with the Gaussian negative log-likelihood, so each entry's variance is
learned with its mean; the covariance it reports is diagonal, each variance times the
scale of its report for the observation mode at the newest frame's age (the step's time
minus that frame's capture time, the age the features carry;
:mod:`~observer_gym.estimation.learned.variance_scale`): log-linear between the knots 0,
0.05, 0.1 and 0.2 s, fitted on validation episodes across the consistency study's pixel
noise, latency and drops (from measurements) or its frames part's image noise and latency
(from frames). From measurements, for the ball's position 3.1 and 3.2 at 0 s, 12 and 7.8
at 0.05 s, 0.5 and 0.7 at 0.2 s; for the tilt and its rate 1.5-1.8 at 0 s, 0.4-0.5 at
0.05 s and 11-27 at 0.2 s: past its training latency (0-0.05 s) the network's own
variance grows with the frames' age for the position faster than its error, and far
slower for the tilt.

**Training data**
(:func:`~observer_gym.train.experiments.learned_observers.ball_table.collect`): episodes
of the env in measurements mode with the LQR plus white action noise (0.005 rad), each
episode's sensor drawn uniformly from :data:`TRAINING_RANGES` (pixel noise, latency and
its jitter, drops, pushes) from the training seed. Four rounds of 60 episodes (DAgger,
Ross, Gordon and Bagnell 2011): in the first the LQR acts on the true state and a network
is fitted; in each later one it acts on the estimate of the network fitted so far, which
takes the ball where the network's own errors lead, and the next network is fitted on
every round's data. After the first round alone, the network erred by 6 mm on its
held-out episodes, but the LQR on its estimate made it err by 56 mm (RMS, 3 episodes at 1
px): it had seen no data where its own errors took the ball. After four rounds: 3.5 and
2.9 mm, velocity 47 and 36 mm/s, tilt 6 and 8 mrad, median NEES/dof 2.2 (the LQR on the
truth: 2.1 and 1.5 mm, NEES/dof 0.46). ``kf`` on the same measurements errs by about
0.02-1.5 mm (docs/observers.md). Outside those ranges (more noise, longer latency,
calibration error, head motion, occluders) the network has seen nothing: its estimate and
its covariance are not to be trusted there.

**From rendered frames** (``obs_mode="rgb"``, the observer names without
``-measurements``) the learned detector
(:mod:`~observer_gym.estimation.ball_table.learned_detector`, a CNN trained on the
perfect detector's pixels of rendered frames) reads each new frame
in the perfect detector's place; the network above is the same, not retrained on the
detector's errors, so what those cost is measured, not hidden
(tests/estimation/test_learned_frames.py). Trained by::

    python -m observer_gym.train.experiments.learned_observers.train --env BallTable-v0

which writes ``estimation/ball_table/learned.pt`` and its report ``learned.json``
(command, data size, held-out errors, sha256; the file is refused if it differs).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from gymnasium import spaces

from observer_gym.envs.ball_table import STATE_DIM, BallTableEnv
from observer_gym.envs.ball_table.layout import BALL_PX, CORNERS_PX, DETECTED
from observer_gym.estimation.ball_table import learned_detector
from observer_gym.estimation.learned.inputs import require_frames_or_measurements
from observer_gym.estimation.learned.variance_scale import load_variance_scale
from observer_gym.estimation.observer import (
    MAX_PIXEL_PX,
    Estimate,
    checked_measurement,
    checked_rgb_frame,
)
from observer_gym.extras import TORCH_MODULES, require_rl

__all__ = [
    "HISTORY_FRAMES",
    "TRAINING_RANGES",
    "WEIGHTS",
    "LearnedFeatures",
    "LearnedObserver",
]

WEIGHTS = Path(__file__).with_name("learned.pt")
HISTORY_FRAMES = 4
MISSING_AGE_S = 1.0  # the age of a frame not received yet
PER_FRAME = 8 + 3 + 2 + 1  # corners, ball, detected flags, age
N_FEATURES = HISTORY_FRAMES * PER_FRAME + 2  # + the last action
ACTION_NOISE_RAD = 0.005
EPISODE_STEPS = 500  # 10 s at the default 50 Hz
# Each training episode's sensor and pushes: uniform in these ranges.
TRAINING_RANGES: dict[str, tuple[float, float]] = {
    "measurement_noise_px": (0.0, 2.0),
    "latency_s": (0.0, 0.05),
    "latency_jitter_s": (0.0, 0.005),
    "frame_drop_prob": (0.0, 0.2),
    "push_rate_hz": (0.0, 1.0),
}


class _Frame(NamedTuple):
    pixels: np.ndarray  # (13,): corners (8), ball (3), detected (2)
    capture_s: float


class LearnedFeatures:
    """The feature vector of each step (see the module docstring), from the step's
    measurement, its info and the last action."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self._frames: list[_Frame] = []  # newest first

    def newest_capture_s(self, info: dict) -> float | None:
        """The capture time of the step's newest frame (``info["frames"]``) if it is newer
        than the last one taken, else None (no new frame this step)."""
        frames = info["frames"]
        if not frames:
            return None
        capture_s = float(frames[-1]["capture_time_s"])
        newest_s = self._frames[0].capture_s if self._frames else -np.inf
        return capture_s if capture_s > newest_s else None

    def new_frame(self, measurement: dict[str, np.ndarray], capture_s: float) -> None:
        corners = np.asarray(measurement[CORNERS_PX], dtype=float)
        ball = np.asarray(measurement[BALL_PX], dtype=float)
        detected = np.asarray(measurement[DETECTED], dtype=float).copy()
        for i, part in enumerate((corners, ball)):
            if not (detected[i] and np.all(np.abs(part) <= MAX_PIXEL_PX)):
                detected[i] = 0.0
                part[:] = 0.0
        pixels = np.concatenate([corners, ball, detected])
        self._frames = [_Frame(pixels, capture_s), *self._frames][:HISTORY_FRAMES]

    def newest_age_s(self, now_s: float) -> float:
        """The newest frame's age at ``now_s`` (s), as the features carry it
        (:data:`MISSING_AGE_S` before the first frame)."""
        return now_s - self._frames[0].capture_s if self._frames else MISSING_AGE_S

    def vector(self, now_s: float, action: np.ndarray | None) -> np.ndarray:
        out = np.zeros(N_FEATURES)
        for k in range(HISTORY_FRAMES):
            block = out[k * PER_FRAME : (k + 1) * PER_FRAME]
            if k < len(self._frames):
                block[:13] = self._frames[k].pixels
                block[13] = now_s - self._frames[k].capture_s
            else:
                block[13] = MISSING_AGE_S
        if action is not None:
            out[-2:] = np.asarray(action, dtype=float).reshape(2)
        return out

    @property
    def frames_seen(self) -> int:
        return len(self._frames)


class LearnedObserver:
    """``learned`` for BallTable-v0 (see the module docstring).

    Args:
        env: the (unwrapped) env, made with ``obs_mode="rgb"`` (frames through the learned
            detector) or ``"measurements"``.
        weights: the weight file (default: the shipped :data:`WEIGHTS`); refused if its
            sha256 is not its report's.
        detector_weights: the learned detector's weight file, from frames (default: the
            shipped :data:`~observer_gym.estimation.ball_table.learned_detector.WEIGHTS`).
    """

    # PyTorch runs the network: the [rl] extra (observer_gym.extras)
    NEEDS_MODULES = TORCH_MODULES

    def __init__(
        self,
        env: BallTableEnv,
        weights: str | Path | None = None,
        detector_weights: str | Path | None = None,
    ) -> None:
        require_rl("the learned observer of BallTable-v0", TORCH_MODULES)
        owner = "the learned observer of BallTable-v0"
        from_frames = require_frames_or_measurements(env, owner) == "rgb"
        from observer_gym.estimation.learned.frame_detector import LearnedDetector
        from observer_gym.estimation.learned.network import load_network  # imports torch

        self.net, self.report = load_network(Path(weights) if weights else WEIGHTS)
        obs_mode = "rgb" if from_frames else "measurements"
        self.variance_scale = load_variance_scale(self.report, obs_mode, STATE_DIM)
        self.detector: LearnedDetector | None = None
        self.image_size_px = (int(env.config.image_width_px), int(env.config.image_height_px))
        if from_frames:
            self.detector = LearnedDetector(Path(detector_weights or learned_detector.WEIGHTS))
            self.detector.check_camera(self.image_size_px, owner)
        else:
            space = env.observation_space
            if not isinstance(space, spaces.Dict):
                raise ValueError(f"{owner}: a measurements env has a Dict space, not {space}")
            self.measurement_space = space
        self.features = LearnedFeatures()

    def measurement(self, obs: Any) -> dict[str, np.ndarray]:
        """The measurement of the step's new frame: the learned detector's reading of the
        picture (rgb), or the perfect detector's measurement, checked."""
        if self.detector is None:
            return checked_measurement("LearnedObserver", obs, self.measurement_space)
        frame = checked_rgb_frame(obs, self.image_size_px, "LearnedObserver")
        return learned_detector.measurement_of(self.detector.detect(frame))

    def reset(self) -> None:
        self.features.reset()

    def predict(self, features: np.ndarray, age_s: float) -> tuple[np.ndarray, np.ndarray]:
        """The network's (mean, covariance) of ``features``, its variances times the
        report's variance scale for this observation mode at the newest frame's age
        ``age_s`` (s; :mod:`~observer_gym.estimation.learned.variance_scale`)."""
        mean, covariance = self.net.predict(features)
        # diagonal: scales each row's entry
        return mean, covariance * self.variance_scale.at(age_s)

    def observe(self, obs: Any, info: dict, action: np.ndarray | None) -> Estimate:
        used = False
        measurement = None
        capture_s = self.features.newest_capture_s(info)
        if capture_s is not None:
            measurement = self.measurement(obs)
            self.features.new_frame(measurement, capture_s)
            used = True
        now_s = float(info["time_s"])
        age_s = self.features.newest_age_s(now_s)  # the age the network reads
        mean, covariance = self.predict(self.features.vector(now_s, action), age_s)
        assert mean.shape == (STATE_DIM,)
        return Estimate(mean, covariance, used, measurement, now_s)
