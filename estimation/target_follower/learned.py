"""TargetFollower's ``learned`` observer: a network trained on the simulator's truth maps
the newest frames' detections to the image state, its target-induced rate and their
covariance (no filter, no model of the image motion).

**Features** (:class:`LearnedFeatures`, :data:`N_FEATURES` = 37 numbers per step): the
newest :data:`HISTORY_FRAMES` frames received (by capture time,
:meth:`~observer_gym.estimation.target_follower.frames.FrameReader.newest`), each as the
perfect detector reports it, (x_i, y_i, d_x) in px (zeros when not detected), its
``detected`` flag, its age (now minus its capture time, s) and the camera's tilt at its
capture (rad, from the frame's nominal ``T_world_cam``), newest first; frames not
received yet are zeros with age :data:`MISSING_AGE_S`. Then the velocity the robot
applied over each of the last :data:`HISTORY_STEPS` steps, (v, omega, omega_t) in m/s,
rad/s, rad/s (``info["applied_action"]``: the last action as the drive applied it), newest
first, and the tilt now (rad). The ages carry latency and drops; the history of frames and
of applied velocities carries the rates and the robot's own part of the image motion.

**Output**: the network (:class:`~observer_gym.estimation.learned.network.GaussianMLP`,
2 x 64 tanh) gives the mean and a diagonal variance of the state's first six entries,
X_i = (x_i, y_i, d_x) in px and X_i^t' in px/s; the rest of the state layout is filled as
every observer of this package fills it (state_layout.py: the robot's pose and tilt from
the step's camera pose, the applied velocity, their covariance 0). ``tracking_valid`` is 1
while a frame of the history had a detection and every variance of X_i is at most the VSE's
reliability threshold (4800 px^2); otherwise the last valid X_i with zero rates and
covariance 4800 I (state_layout.lost_estimate, as ``kf`` reports a lost track).
``target_visible`` is 1 when this step's new frame had a detection.

**Training data**
(:func:`~observer_gym.train.experiments.learned_observers.target_follower.collect`):
episodes of 300 steps (30 s) of the env in measurements mode with the VTC plus white
action noise (:data:`ACTION_NOISE`), each episode's sensor and world drawn uniformly from
:data:`TRAINING_RANGES` from the training seed. Those are the options the benchmark's
levels vary for measurements (train/experiments/benchmark/suites/v1/target_follower.json;
"field": 5 px, 50 ms with 10 ms latency jitter and 2 ms capture jitter, 10 % drops,
pushes at 0.5 Hz, an occluder at 0.1 Hz): the ranges run from 0 to the field level's
value. Rounds (DAgger, Ross, Gordon and Bagnell 2011): in the first the VTC acts on the
true state, in each later one on the estimate of the network fitted to the rounds before;
each network is fitted on every round's data. Samples are kept where the target is in
front of the camera (the truth's ``tracking_valid``) and a frame of the history had a
detection (elsewhere the observer reports itself lost). Four rounds of :data:`EPISODES` =
100 episodes: 101 898 samples, 99 s of wall time on one core (load average 6); the
weights, 37 -> 2 x 64 tanh -> 6 + 6, are 34 367 bytes. Held out (the last 80 episodes, of
the last round): RMSE 4.07, 2.48, 1.14 px and 12.5, 7.3, 2.2 px/s, NEES/dof 1.11. On
seeds the training never drew, the VTC on this estimate, 3 episodes of 300 steps at 2 px:
1.12, 1.00, 0.82 px and 7.2, 4.9, 1.7 px/s, median NEES/dof 0.57 (``kf`` on the same
detections: 0.91, 0.91, 0.62 px and 5.7, 5.3, 1.3 px/s); at 5 px 2.38, 2.09, 1.53 px,
NEES/dof 1.77 (tests/estimation/test_learned_target_follower.py). After the first round
alone (``--rounds 1``, 19 s) its held-out d_x erred by 0.71 px, but with the VTC on its
estimate, the same 3 episodes at 2 px, by 2.02 px (x_i 1.56, y_i 1.40), and the target
stayed 15.9 px from the centre on average (9.6 after four rounds): it had seen no data
where its own errors took the robot.

**Not trusted** (the network has seen nothing of them): calibration error of any kind
(the benchmark's lab and field levels have 0.5-2 degrees of rotation, 1-5 % focal,
2-5 px principal point, 5-20 mm translation), wheel quantisation and acceleration limits
(the field level quantises), another frame rate, focal length, target size or target
motion than the default random walk, more than 5 px of pixel noise, latency beyond
50 ms (+10 ms jitter), drops beyond 10 %, pushes beyond 0.5 Hz, occluders more often
than 0.1 Hz or held longer than the default 3 s.

**From rendered frames** (``obs_mode="rgb"``, the names without ``-measurements``) the
learned detector (:mod:`~observer_gym.estimation.target_follower.learned_detector`, a CNN
trained on the perfect detector's pixels of rendered frames) reads each new frame in the
perfect detector's place; the network above is the same, not retrained on the detector's
errors (tests/estimation/test_learned_frames.py measures what they cost).

Trained by::

    python -m observer_gym.train.experiments.learned_observers.train --env TargetFollower-v0

which writes ``estimation/target_follower/learned.pt`` and its report ``learned.json``
(command, data size, held-out errors after each round, sha256; the file is refused if it
differs). The figures measured on new seeds are in docs/observers.md and
tests/estimation/test_learned_target_follower.py.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from observer_gym.envs.target_follower import STATE_DIM, TargetFollowerEnv
from observer_gym.estimation.learned.inputs import require_frames_or_measurements
from observer_gym.estimation.observer import Estimate
from observer_gym.estimation.target_follower.filters import VSEParams
from observer_gym.estimation.target_follower.frames import FrameDetection, FrameReader
from observer_gym.estimation.target_follower.state_layout import (
    RobotStep,
    lost_estimate,
    state_estimate,
)
from observer_gym.extras import TORCH_MODULES, require_rl

__all__ = [
    "HISTORY_FRAMES",
    "HISTORY_STEPS",
    "TRAINING_RANGES",
    "WEIGHTS",
    "LearnedEstimator",
    "LearnedFeatures",
    "LearnedObserver",
]

WEIGHTS = Path(__file__).with_name("learned.pt")
HISTORY_FRAMES = 4
HISTORY_STEPS = 4  # applied velocities kept
MISSING_AGE_S = 1.0  # the age of a frame not received yet
PER_FRAME = 3 + 1 + 1 + 1  # (x_i, y_i, d_x), detected, age, tilt at capture
N_FEATURES = HISTORY_FRAMES * PER_FRAME + 3 * HISTORY_STEPS + 1  # + the tilt now
N_OUT = 6  # X_i (px) and X_i^t' (px/s): the state's first six entries
HIDDEN = 64
EPISODE_STEPS = 300  # 30 s at the default 10 frames/s
EPISODES = 100  # per round: the training command's default --episodes
# the VSE's reliability threshold (px^2): an X_i variance above it is "lost"
RELIABILITY_THRESHOLD_PX2 = VSEParams().reliability_threshold
# Each training episode's sensor and world: uniform in these ranges (0 to the benchmark
# field level's value for measurements).
TRAINING_RANGES: dict[str, tuple[float, float]] = {
    "measurement_noise_px": (0.0, 5.0),
    "latency_s": (0.0, 0.05),
    "latency_jitter_s": (0.0, 0.01),
    "jitter_s": (0.0, 0.002),
    "frame_drop_prob": (0.0, 0.1),
    "push_rate_hz": (0.0, 0.5),
    "occluder_rate_hz": (0.0, 0.1),
}


class _Frame(NamedTuple):
    z_px: np.ndarray  # (3,), zeros when not detected
    detected: float
    capture_s: float
    tilt_rad: float


class LearnedFeatures:
    """The feature vector of each step (see the module docstring), from the step's new
    frame (if any) and the robot's step."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self._frames: list[_Frame] = []  # newest first
        self._applied: list[np.ndarray] = []  # newest first
        self._tilt_rad = 0.0

    def add(self, frame: FrameDetection | None, robot: RobotStep) -> None:
        """One step: its new frame (None: none arrived) and what the robot reports."""
        if frame is not None:
            detected = frame.z_px is not None
            z = np.asarray(frame.z_px, dtype=float) if detected else np.zeros(3)
            new = _Frame(z, float(detected), frame.capture_time_s, float(frame.tilt_rad))
            self._frames = [new, *self._frames][:HISTORY_FRAMES]
        self._applied = [np.asarray(robot.applied, dtype=float), *self._applied][:HISTORY_STEPS]
        self._tilt_rad = float(robot.tilt_rad)

    @property
    def any_detected(self) -> bool:
        """Whether a frame of the history had a detection."""
        return any(f.detected for f in self._frames)

    def vector(self, now_s: float) -> np.ndarray:
        """The features with ``now_s`` as "now" (the step's time; ``learned-kf``: the new
        frame's capture time)."""
        out = np.zeros(N_FEATURES)
        for k in range(HISTORY_FRAMES):
            block = out[k * PER_FRAME : (k + 1) * PER_FRAME]
            if k < len(self._frames):
                f = self._frames[k]
                block[:3] = f.z_px
                block[3] = f.detected
                # age_k = now - t_capture,k (s)
                block[4] = now_s - f.capture_s
                block[5] = f.tilt_rad
            else:
                block[4] = MISSING_AGE_S
        start = HISTORY_FRAMES * PER_FRAME
        for k, applied in enumerate(self._applied):
            out[start + 3 * k : start + 3 * k + 3] = applied
        out[-1] = self._tilt_rad
        return out


class LearnedEstimator:
    """The features and the network's estimate in the state layout, step by step: what
    :class:`LearnedObserver` reports and what the DAgger rounds of
    :func:`~observer_gym.train.experiments.learned_observers.target_follower.collect` act on."""

    def __init__(self, net: Any) -> None:
        self.net = net
        self.features = LearnedFeatures()
        self.reset()

    def reset(self) -> None:
        self.features.reset()
        self._last_image = np.zeros(3)

    def step(
        self, frame: FrameDetection | None, robot: RobotStep
    ) -> tuple[np.ndarray, np.ndarray, bool]:
        """(mean (15,), covariance (15, 15), valid) at the robot's step time."""
        self.features.add(frame, robot)
        visible = frame is not None and frame.z_px is not None
        if self.features.any_detected:
            # (X_i, X_i^t'), diag(sigma^2) = network(features at now = the step's time)
            mean6, cov6 = self.net.predict(self.features.vector(robot.time_s))
            # valid: max_j sigma^2_j of X_i <= 4800 px^2, the VSE's reliability threshold
            if np.max(np.diag(cov6)[:3]) <= RELIABILITY_THRESHOLD_PX2:
                self._last_image = mean6[:3].copy()
                mean, cov = state_estimate(mean6[:3], mean6[3:], cov6, robot, True, visible)
                return mean, cov, True
        mean, cov = lost_estimate(self._last_image, RELIABILITY_THRESHOLD_PX2, robot, visible)
        return mean, cov, False


class LearnedObserver:
    """``learned`` for TargetFollower-v0 (see the module docstring).

    Args:
        env: the (unwrapped) env, made with ``obs_mode="rgb"`` (frames through the learned
            detector) or ``"measurements"``.
        weights: the weight file (default: the shipped :data:`WEIGHTS`); refused if its
            sha256 is not its report's.
        detector_weights: the learned detector's weight file, from frames (default: the
            shipped one; refused if changed).
    """

    # PyTorch runs the network: the [rl] extra (observer_gym.extras)
    NEEDS_MODULES = TORCH_MODULES

    def __init__(
        self,
        env: TargetFollowerEnv,
        weights: str | Path | None = None,
        detector_weights: str | Path | None = None,
    ) -> None:
        require_rl("the learned observer of TargetFollower-v0", TORCH_MODULES)
        owner = "the learned observer of TargetFollower-v0"
        from_frames = require_frames_or_measurements(env, owner) == "rgb"
        from observer_gym.estimation.learned.network import load_network  # imports torch
        from observer_gym.estimation.target_follower.learned_detector import (
            LearnedTargetDetector,
        )

        net, self.report = load_network(Path(weights) if weights else WEIGHTS)
        self.estimator = LearnedEstimator(net)
        detector = None
        if from_frames:
            size_px = (int(env.config.image_width_px), int(env.config.image_height_px))
            path = Path(detector_weights) if detector_weights else None
            detector = LearnedTargetDetector(path, size_px, owner)
        self.frames = FrameReader(env, detector, owner="LearnedObserver")
        self.delta_y_m = env.calibration["delta_y_m"]

    @property
    def net(self) -> Any:
        return self.estimator.net

    def reset(self) -> None:
        self.frames.reset()
        self.estimator.reset()

    def observe(self, obs: Any, info: dict, action: np.ndarray | None) -> Estimate:
        if action is None:  # after a reset
            self.reset()
        robot = RobotStep.from_info(info, action, self.delta_y_m)
        frame = self.frames.newest(obs, info)
        mean, cov, _ = self.estimator.step(frame, robot)
        assert mean.shape == (STATE_DIM,)
        z = None if frame is None else frame.z_px
        return Estimate(mean, cov, z is not None, z, robot.time_s)
