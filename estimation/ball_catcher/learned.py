"""BallCatcher's ``learned`` observer: a network trained on the simulator's truth maps the
newest frames' detections of every camera to the ball's state and its covariance (no
triangulation, no viewline filter).

**Features** (:class:`LearnedFeatures`, 65 numbers per step for the two cameras it is
trained with): per camera, its newest :data:`HISTORY_FRAMES` frames received (by capture
time: a frame delivered late is put in its place, one older than all eight kept is
dropped), each as the perfect detector reports it: the ball's pixel (u, v) in px, its
``detected`` flag, and its age ``now_s - capture_s`` (s), newest first. A frame without a
detection (or with NaN, inf or a pixel beyond
:data:`~observer_gym.estimation.observer.MAX_PIXEL_PX`) reports the image's centre, which
the inputs' standardisation takes to about 0 (with zeros, 3 standard deviations off, the
first network erred by 20-30 cm once camera 0 lost the ball near the box); a slot no frame
has filled yet is the image's centre, not detected, with age :data:`MISSING_AGE_S`. Last,
the time since the launch ``now_s`` (s): the throw leaves at t = 0, as the viewline
filter's prior assumes. The ages carry latency, jitter, drops and the cameras' phases;
eight frames per camera span 160 ms at 50 Hz.

**Estimate**: the network's outputs are the ball's position (m) and velocity (m/s), the
state's first six entries, with a diagonal covariance (each entry's variance learned with
its mean: Gaussian negative log-likelihood), times the variance scale of its report for
the observation mode (:mod:`~observer_gym.estimation.learned.variance_scale`). From
measurements it depends on the newest kept frame's age and on four numbers of the env's
declared sensor (``env.sensor_spec``, the data sheet ``kf`` reads for its R and its
calibration consider parameters: ``measurement_noise_std_px``, ``frame_drop_prob``,
``calib_rotation_error_deg``, ``calib_focal_error``), inputs of the variance, not of the
network's mean; fitted jointly on 500 validation throws that vary the consistency
study's noise, latency, drops, rotation and focal error in turn. At the default 0.5 px
with no drops, no calibration error and a young frame its factors are 1.15, 0.34, 0.38
for the position and 0.37-0.48 for the velocity (inside its training range the network
claims more error than it has); at 4 px 7.0, 8.0, 6.7 and 5.5-7.6 (past its training
range, 2 px, it claims too little); with half the frames dropped 3.6, 2.1, 1.6; at 1
degree of rotation error 6.2, 9.1, 4.0, at 5 % focal error 7.8, 1.6, 0.8 (errors it never
saw); at 0.2 s of age 10.5, 1.0, 5.0, where it errs most along the throw. From frames
by the age alone: 1 while the newest frame is at most 0.05 s old, beyond, by that age,
9.7, 1.0, 5.9 and 1.4-11.2 at 0.2 s. The box's entries are what
the env reports as the robot's own kinematics (``info["box_pos_world_m"]``,
``info["box_vel_world_mps"]``) with zero variance, as ``kf`` fills them; the network
does not read them (the ball's flight up to its first touch of the box does not depend
on the box).

**Network**: :class:`~observer_gym.estimation.learned.network.GaussianMLP` (2 x 128
tanh, the shared default), weights in ``learned.pt`` (:data:`WEIGHT_BYTES` bytes,
111 kB), checked by sha256 against its report ``learned.json``. Held out (the last 500
of 2500 training throws, every free-flight step, from the launch on): position RMSE 24,
16, 16 mm (x, y, z), velocity 194, 87, 100 mm/s, NEES/dof 1.14. On throws of seeds the
training never drew (10**6 on, 1 px, the ``intercept`` controller on its estimate, from
0.1 s to the crossing), the figures and bounds are in
tests/estimation/test_learned_ball_catcher.py and docs/observers.md.

**Training data**
(:func:`~observer_gym.train.experiments.learned_observers.ball_catcher.collect`): throws
of the env in measurements mode caught by the ``intercept`` controller, each episode's
sensor drawn from :data:`TRAINING_RANGES` from the training seed: pixel noise 0-2 px,
latency 0-10 ms, latency jitter 0-3 ms, capture jitter 0-2 ms, drops 0-10 %, camera
preset "alternating" or "random_offsets" (the options the benchmark's levels vary, ideal
to field, docs/benchmark.md). Only the steps of the ball's free flight
(``info["ball_in_flight"]``: before its first touch of the box) are samples: after the
touch no model holds and the estimate there is not claimed. DAgger rounds (``act_with``:
the controller acts on the network fitted so far) are supported as for BallTable, but add
only throws of new seeds: the ball's free flight, and so every sample, does not depend on
the actions (the perfect detector models no occlusion by the box), so the shipped weights
are one round.

**Outside the training ranges** the network has seen nothing, and its estimate is not to
be trusted there: more pixel noise, latency above 10 ms or its jitter above 3 ms, drops
above 10 %, any calibration error, air drag, the "synchronised" or "single" preset,
another number of cameras (refused at construction), another frame rate, control period
or throw distribution (launch point, flight time, target radius), and the steps after
the ball's first touch of the box. Its covariance is measured up to the consistency
study's largest pixel noise (4 px), latency (0.2 s with 0.01 s of jitter), drops (half
the frames), rotation error (2 degrees) and focal error (5 %), one at a time, where the
variance scale holds the median NEES/dof inside [1/3, 3] (docs/results/consistency.md);
nowhere else. Two at once are the scale's assumption (each multiplies the variance
independently), not a measurement: at 0 px with 0.2 s of latency, on the tests' throws,
2.77.

**From rendered frames** (``obs_mode="rgb"``, the names without ``-measurements``) the
learned detector (:mod:`~observer_gym.estimation.ball_catcher.learned_detector`, a
fully convolutional network trained on the perfect detector's pixels of rendered
frames, read at full resolution) gives each delivered frame's (u, v) or no detection in
the perfect detector's place; the network above is the same, not retrained on the
detector's errors (tests/estimation/test_learned_ball_catcher_frames.py measures what
they cost). From measurements (``learned-measurements``) it reads the perfect
detector's report.

Trained by (the held-out figures are in ``learned.json`` and docs/observers.md)::

    python -m observer_gym.train.experiments.learned_observers.train \\
        --env BallCatcher-v1 --episodes 2500 --rounds 1
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from observer_gym.envs.ball_catcher import BallCatcherEnv
from observer_gym.estimation.ball_catcher.frames import FrameReader
from observer_gym.estimation.ball_catcher.state_layout import state_estimate
from observer_gym.estimation.learned.inputs import require_frames_or_measurements
from observer_gym.estimation.learned.variance_scale import (
    declared_numbers,
    load_variance_scale,
)
from observer_gym.estimation.observer import Estimate
from observer_gym.extras import TORCH_MODULES, require_rl

__all__ = [
    "CAMERAS",
    "HISTORY_FRAMES",
    "TRAINING_RANGES",
    "WEIGHTS",
    "LearnedFeatures",
    "LearnedObserver",
]

WEIGHTS = Path(__file__).with_name("learned.pt")
WEIGHT_BYTES = 111_423  # the size of the shipped learned.pt (checked by the tests)
CAMERAS = 2  # the rig it is trained with (the default presets' two cameras)
HISTORY_FRAMES = 8  # per camera
MISSING_AGE_S = 1.0  # the age of a slot no frame has filled yet
PER_FRAME = 4  # u (px), v (px), detected, age (s)
N_FEATURES = CAMERAS * HISTORY_FRAMES * PER_FRAME + 1  # + the time since the launch
# Each training episode's sensor: uniform in these ranges (a tuple of names: one of them,
# uniformly).
TRAINING_RANGES: dict[str, tuple[Any, ...]] = {
    "measurement_noise_px": (0.0, 2.0),
    "latency_s": (0.0, 0.01),
    "latency_jitter_s": (0.0, 0.003),
    "jitter_s": (0.0, 0.002),
    "frame_drop_prob": (0.0, 0.1),
    "camera_preset": ("alternating", "random_offsets"),
}


class LearnedFeatures:
    """The feature vector of each step (see the module docstring) from the frames
    delivered so far (:meth:`add`) and the step's time (:meth:`vector`).

    Args:
        cameras: the env's number of cameras.
        centre_px: the (u, v) reported for a frame without a detection (the image's
            centre, ((width - 1) / 2, (height - 1) / 2)).
    """

    def __init__(
        self, cameras: int = CAMERAS, centre_px: tuple[float, float] = (159.5, 119.5)
    ) -> None:
        self.cameras = cameras
        self.centre_px = (float(centre_px[0]), float(centre_px[1]))
        self.reset()

    def reset(self) -> None:
        # per camera, newest first: (capture_s, u_px, v_px, detected)
        self._frames: list[list[tuple[float, float, float, float]]] = [
            [] for _ in range(self.cameras)
        ]

    def add(self, camera: int, capture_s: float, uv_px: np.ndarray | None) -> bool:
        """Keep a delivered frame of ``camera`` (``uv_px`` None: not detected) in its place
        by capture time; False if it was not kept (older than every kept frame of a full
        history, or a frame already kept)."""
        kept = self._frames[camera]
        if any(c == capture_s for c, *_ in kept):
            return False
        if uv_px is None:
            entry = (capture_s, *self.centre_px, 0.0)
        else:
            entry = (capture_s, float(uv_px[0]), float(uv_px[1]), 1.0)
        at = sum(1 for c, *_ in kept if c > capture_s)
        if at >= HISTORY_FRAMES:
            return False
        kept.insert(at, entry)
        del kept[HISTORY_FRAMES:]
        return True

    def vector(self, now_s: float) -> np.ndarray:
        """(``cameras`` x 8 x (u, v, detected, age), now_s)."""
        out = np.zeros(self.cameras * HISTORY_FRAMES * PER_FRAME + 1)
        u0, v0 = self.centre_px
        for camera, kept in enumerate(self._frames):
            for k in range(HISTORY_FRAMES):
                i = (camera * HISTORY_FRAMES + k) * PER_FRAME
                if k < len(kept):
                    capture_s, u, v, detected = kept[k]
                    out[i : i + 4] = (u, v, detected, now_s - capture_s)
                else:
                    out[i : i + 4] = (u0, v0, 0.0, MISSING_AGE_S)
        out[-1] = now_s
        return out

    def newest_capture_s(self) -> float:
        """The capture time (s) of the newest frame kept of any camera (-inf: none yet)."""
        return max((kept[0][0] for kept in self._frames if kept), default=-np.inf)

    def frames_kept(self, camera: int) -> int:
        return len(self._frames[camera])


def checked_env(env: Any, owner: str, cameras: int) -> BallCatcherEnv:
    """``env`` if a learned observer can read it: a BallCatcherEnv in rgb mode (frames
    through the learned detector) or measurements mode, with the rig's ``cameras``
    cameras; else ValueError in one line."""
    if not isinstance(env, BallCatcherEnv):
        raise ValueError(f"{owner} needs a BallCatcherEnv, got {type(env).__name__}")
    require_frames_or_measurements(env, f"{owner} of BallCatcher-v1")
    if env.num_cameras != cameras:
        raise ValueError(
            f"{owner} of BallCatcher-v1 is trained with {cameras} cameras, the env has "
            f"{env.num_cameras} (camera_preset {env.config.camera_preset!r}, num_cameras "
            f"{env.config.num_cameras})"
        )
    return env


class LearnedObserver:
    """``learned`` for BallCatcher-v1 (see the module docstring).

    Args:
        env: the (unwrapped) env, made with ``obs_mode="rgb"`` (frames through the learned
            detector) or ``"measurements"``, and two cameras.
        weights: the weight file (default: the shipped :data:`WEIGHTS`); refused if its
            sha256 is not its report's.
        detector_weights: the learned detector's weight file, from frames (default: the
            shipped :data:`~observer_gym.estimation.ball_catcher.learned_detector.WEIGHTS`;
            refused if changed).
    """

    # PyTorch runs the network: the [rl] extra (observer_gym.extras)
    NEEDS_MODULES = TORCH_MODULES

    def __init__(
        self,
        env: BallCatcherEnv,
        weights: str | Path | None = None,
        detector_weights: str | Path | None = None,
    ) -> None:
        require_rl("the learned observer of BallCatcher-v1", TORCH_MODULES)
        from observer_gym.estimation.learned.network import load_network  # imports torch

        self.net, self.report = load_network(Path(weights) if weights else WEIGHTS)
        cameras = (self.net.n_in - 1) // (HISTORY_FRAMES * PER_FRAME)
        env = checked_env(env, "LearnedObserver", cameras)
        self.variance_scale = load_variance_scale(self.report, env.config.obs_mode, self.net.n_out)
        # the declared sensor's numbers the scale reads (its data sheet, as kf's R reads
        # it, never the realised draws): inputs of the variance, not of the mean
        self.declared = declared_numbers(env.sensor_spec, self.variance_scale)
        detector = None
        if env.config.obs_mode == "rgb":
            from observer_gym.estimation.ball_catcher.learned_detector import (
                LearnedBallDetector,
            )

            path = Path(detector_weights) if detector_weights else None
            owner = "the learned observer of BallCatcher-v1"
            detector = LearnedBallDetector(path, env.rig.image_size_px, owner)
        self.pixels = FrameReader(env.config, detector, owner="LearnedObserver")
        self.features = LearnedFeatures(cameras, image_centre_px(env))

    def reset(self) -> None:
        self.features.reset()

    def read_frames(self, info: dict) -> tuple[bool, list[dict[str, Any]]]:
        """Keep the step's delivered frames (``info["frames"]``); (whether a kept one
        shows the ball, the step's detections as ``kf`` reports them)."""
        measurements = []
        detected = False
        for frame in info["frames"]:
            uv = self.pixels.detect(frame)
            camera = int(frame["camera_id"])
            measurements.append({"camera_id": camera, "uv_px": uv})
            kept = self.features.add(camera, float(frame["capture_time_s"]), uv)
            detected |= kept and uv is not None
        return detected, measurements

    def predict(self, now_s: float) -> tuple[np.ndarray, np.ndarray]:
        """The network's ball state and diagonal covariance at ``now_s`` from the frames
        kept, its variances times the report's variance scale for the observation mode at
        the newest kept frame's age and the declared sensor's numbers it reads
        (:mod:`~observer_gym.estimation.learned.variance_scale`; no frame yet: held at the
        last age knot's scale)."""
        mean, covariance = self.net.predict(self.features.vector(now_s))
        age_s = now_s - self.features.newest_capture_s()
        # diagonal: scales each row's entry
        return mean, covariance * self.variance_scale.at(age_s, self.declared)

    def observe(self, obs: Any, info: dict, action: np.ndarray | None) -> Estimate:
        used, measurements = self.read_frames(info)
        now_s = float(info["time_s"])
        ball, ball_covariance = self.predict(now_s)
        mean, covariance = state_estimate(ball, ball_covariance, info)
        return Estimate(mean, covariance, used, measurements or None, now_s)


def image_centre_px(env: BallCatcherEnv) -> tuple[float, float]:
    """((width - 1) / 2, (height - 1) / 2) of the env's images (px)."""
    width, height = env.rig.image_size_px
    return 0.5 * (width - 1), 0.5 * (height - 1)
