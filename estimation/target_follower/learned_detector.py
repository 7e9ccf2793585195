"""TargetFollower's learned detector: the network that reads a rendered frame in place of
the orange-blob detector, for the ``learned`` and ``learned-kf`` observers from frames.

Per 320 x 240 frame (resized to :data:`NET_SIZE_PX`) it gives what the perfect detector
reports in ``obs_mode="measurements"``: the target's image state (x_i, y_i, d_x) in
pixels, each with a variance, and whether it is detected
(:mod:`~observer_gym.estimation.learned.frame_detector`). :class:`LearnedTargetDetector`
has the blob detector's interface, so the observers' frame reader
(estimation/target_follower/frames.py) takes it in its place, and the ``learned`` network
and ``learned-kf``'s filter downstream are those of the measurements.

**Training data**
(:func:`~observer_gym.train.experiments.learned_observers.target_follower.collect_frames`,
with
:func:`~observer_gym.train.experiments.learned_observers.frame_data.collect_lockstep`):
episodes run in rgb and in measurements mode in lockstep; the rgb frame is the input, the
measurement (no noise) its label. The VTC acts on the true state plus white noise on (v,
omega, omega_t), its std :data:`ACTION_NOISE` times a factor drawn per episode from
:data:`ACTION_NOISE_RANGE`; pushes, occluders and image noise are drawn per episode from
:data:`FRAME_RANGES`; every :data:`STRIDE`-th frame is kept. Trained by::

    python -m observer_gym.train.experiments.learned_observers.train_detector \\
        --env TargetFollower-v0

which writes :data:`WEIGHTS` and its report ``learned_detector.json``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from observer_gym.envs.target_follower import DETECTED, TARGET_PX

__all__ = [
    "ACTION_NOISE",
    "FRAME_RANGES",
    "NET_SIZE_PX",
    "VALUE_PARTS",
    "WEIGHTS",
    "LearnedTargetDetector",
    "labels_of",
]

WEIGHTS = Path(__file__).with_name("learned_detector.pt")
NET_SIZE_PX = (128, 96)  # the network's input (width, height): the 320 x 240 frame / 2.5
CAMERA_PX = (320, 240)  # the camera image it is trained on (the env's default)
VALUE_PARTS = [0, 0, 0]  # (x_i, y_i, d_x): one part, the target
EPISODES = 100
EPISODE_STEPS = 300  # 30 s at the default 10 frames/s
STRIDE = 2
# white noise on the VTC's (v, omega, omega_t) while collecting training episodes: m/s,
# rad/s, rad/s; the learned observer's episodes take it as it is, this
# detector's times a factor drawn per episode from ACTION_NOISE_RANGE
ACTION_NOISE = (0.05, 0.1, 0.05)
ACTION_NOISE_RANGE = (0.0, 3.0)  # times ACTION_NOISE
FRAME_RANGES: dict[str, tuple[float, float]] = {
    "push_rate_hz": (0.0, 0.5),
    "occluder_rate_hz": (0.0, 0.1),
    "image_noise_std": (0.0, 4.0),
}


def labels_of(measurement: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """(values (3,), detected (1,)) of a perfect measurement: the network's targets."""
    return (
        np.asarray(measurement[TARGET_PX], float),
        np.asarray(measurement[DETECTED], float).reshape(1),
    )


class LearnedTargetDetector:
    """The learned detector with the blob detector's interface: ``detect(image, K)`` ->
    (x_i, y_i, d_x) or None.

    Args:
        path: the weight file (default :data:`WEIGHTS`); refused if changed.
        image_size_px: the env's camera image (W, H); ValueError unless it is the one the
            network was trained on.
        owner: the observer's name, for that error.
    """

    def __init__(self, path: Path | None, image_size_px: tuple[int, int], owner: str) -> None:
        from observer_gym.estimation.learned.frame_detector import LearnedDetector

        self.network = LearnedDetector(Path(path or WEIGHTS))
        self.network.check_camera(image_size_px, owner)

    def detect(self, image: np.ndarray, K: np.ndarray) -> np.ndarray | None:
        """(x_i, y_i, d_x) in pixels, or None when the network says the target is not
        detected. ``K`` is not read: the network learnt the nominal camera."""
        detection = self.network.detect(image)
        return detection.values if bool(detection.detected[0]) else None
