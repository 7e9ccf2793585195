"""BallTable's learned detector: the network that reads a rendered frame in place of the
image stage, for the ``learned`` and ``learned-kf`` observers from frames.

Per 320 x 240 frame (resized to :data:`NET_SIZE_PX`) it gives what the perfect detector
reports in ``obs_mode="measurements"``: the red top's 4 corners and the ball's centre and
semi-major axis (11 pixel values, each with a variance) and the two ``detected`` flags
(:mod:`~observer_gym.estimation.learned.frame_detector`). Its output is a measurement of
the env's measurement layout (:func:`measurement_of`), so the ``learned`` network and
``learned-kf``'s filters downstream are those of the measurements: the detector is the
only part that reads pixels.

**Training data**
(:func:`~observer_gym.train.experiments.learned_observers.ball_table.collect_frames`,
with
:func:`~observer_gym.train.experiments.learned_observers.frame_data.collect_lockstep`):
episodes run in rgb and in measurements mode in lockstep; the rgb frame is the input, the
measurement (no noise) its label. The LQR acts on the true state plus white tilt noise
whose std is drawn per episode from :data:`ACTION_NOISE_RANGE_RAD`, so the ball is seen
both near the centre and rolling across the table; pushes and image noise are drawn per
episode from :data:`FRAME_RANGES`; every :data:`STRIDE`-th frame is kept. Calibration
error, head motion and occluders are not in the data. Trained by::

    python -m observer_gym.train.experiments.learned_observers.train_detector --env BallTable-v0

which writes :data:`WEIGHTS` and its report ``learned_detector.json``.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from observer_gym.envs.ball_table.layout import BALL_PX, CORNERS_PX, DETECTED

if TYPE_CHECKING:  # frame_detector imports torch, which `import observer_gym` must not
    from observer_gym.estimation.learned.frame_detector import Detection

__all__ = [
    "ACTION_NOISE_RANGE_RAD",
    "FRAME_RANGES",
    "NET_SIZE_PX",
    "VALUE_PARTS",
    "WEIGHTS",
    "labels_of",
    "measurement_of",
]

WEIGHTS = Path(__file__).with_name("learned_detector.pt")
NET_SIZE_PX = (128, 96)  # the network's input (width, height): the 320 x 240 frame / 2.5
CAMERA_PX = (320, 240)  # the camera image it is trained on (the env's default)
# corners (8 values) belong to part 0 (the table), the ball's (u, v, semi-major) to part 1
VALUE_PARTS = [0] * 8 + [1] * 3
EPISODES = 120
EPISODE_STEPS = 250  # 5 s at the default 50 Hz
STRIDE = 2
ACTION_NOISE_RANGE_RAD = (0.0, 0.04)
FRAME_RANGES: dict[str, tuple[float, float]] = {
    "push_rate_hz": (0.0, 1.0),
    "image_noise_std": (0.0, 4.0),
}


def labels_of(measurement: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """(values (11,), detected (2,)) of a perfect measurement: the network's targets."""
    values = np.concatenate(
        [np.asarray(measurement[CORNERS_PX], float), np.asarray(measurement[BALL_PX], float)]
    )
    return values, np.asarray(measurement[DETECTED], float)


def measurement_of(detection: Detection) -> dict[str, np.ndarray]:
    """The learned detector's output in the measurement layout (a part not detected is
    zeros with its flag 0, as the perfect detector reports it)."""
    table, ball = bool(detection.detected[0]), bool(detection.detected[1])
    values = detection.values.astype(np.float32)
    return {
        CORNERS_PX: values[:8] if table else np.zeros(8, np.float32),
        BALL_PX: values[8:11] if ball else np.zeros(3, np.float32),
        DETECTED: np.array([table, ball], dtype=np.int8),
    }
