"""BallCatcher's learned detector: the network that reads each camera's rendered frame in
place of the green-blob detector, for the ``learned`` and ``learned-kf`` observers from
frames.

Per 320 x 240 frame, read at its full resolution (the ball is 4-12 px across: the resize
to 128 x 96 of BallTable's and TargetFollower's detectors would leave 2-5 px), it gives
what the perfect detector reports in ``obs_mode="measurements"``: the ball's centre
(u, v) in pixels, with a variance each, and whether it is in the image
(:mod:`~observer_gym.estimation.learned.heatmap_detector`: a small fully convolutional
network, a heat map at stride 4 with sub-pixel offsets and log-variances, shared by the
cameras). :class:`LearnedBallDetector` has the blob detector's interface, so the
observers' frame reader (estimation/ball_catcher/frames.py) takes it in its place, and
the ``learned`` network and ``learned-kf``'s filter downstream are those of the
measurements: the detector is the only part that reads pixels.

**Training data**
(:func:`~observer_gym.train.experiments.learned_observers.ball_catcher.collect_frames`,
with
:func:`~observer_gym.train.experiments.learned_observers.frame_data.collect_lockstep`):
throws run in rgb and in measurements mode in lockstep; every frame delivered (each
camera's, 50 frames/s) is an input, the perfect detector's noise-free pixel of the same
frame its label. The ``intercept`` controller acts on the true state plus white velocity
noise whose std is drawn per episode from :data:`ACTION_NOISE_RANGE_MPS`, so the box and
arm are seen in and away from their usual places; image noise is drawn per episode from
:data:`FRAME_RANGES`. The network trains on :data:`CROP_PX`-square crops, two per frame:
one placed at random around the ball's centre (uniform within the crop; only when the
label has the ball in the image) and one anywhere in the frame (mostly without the ball:
white background, box, arm), and runs on the whole frame (its convolutions are
translation-equivariant). The label is the projected centre whether or not the ball is
hidden (the perfect detector models no occlusion by the box or arm); such frames are few
and stay in the data. Calibration error, another field of view or image size are not in
the data. Trained by::

    python -m observer_gym.train.experiments.learned_observers.train_detector --env BallCatcher-v1

which writes :data:`WEIGHTS` and its report ``learned_detector.json`` (held out: crops
of the last fifth of the episodes; the full-frame figures on a seed the training never
drew are in tests/estimation/test_learned_ball_catcher_frames.py and docs/observers.md).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # heatmap_detector imports torch, which `import observer_gym` must not
    from observer_gym.estimation.learned.frame_training import FrameDataset
    from observer_gym.estimation.learned.heatmap_detector import PointDetection, PointHeatmapNet

__all__ = [
    "ACTION_NOISE_RANGE_MPS",
    "CAMERA_PX",
    "CROP_PX",
    "FRAME_RANGES",
    "WEIGHTS",
    "LearnedBallDetector",
    "fit",
    "save",
]

WEIGHTS = Path(__file__).with_name("learned_detector.pt")
WEIGHT_BYTES = 102_549  # the size of the shipped learned_detector.pt (checked by the tests)
CAMERA_PX = (320, 240)  # the camera image it is trained on (the env's default)
CROP_PX = 64  # the training crops' side (px), a multiple of the network's stride (4)
EPISODES = 300
EPOCHS = 8
EPISODE_STEPS = 200  # the registered limit (2 s); a throw ends at the box's plane
STRIDE = 1  # every step: each delivered frame once
ACTION_NOISE_RANGE_MPS = (0.0, 0.3)
FRAME_RANGES: dict[str, tuple[float, float]] = {"image_noise_std": (0.0, 8.0)}
# the labels are the projected centre without noise
ENV_KWARGS: dict[str, Any] = {"measurement_noise_px": 0.0}


def fit(data: FrameDataset, seed: int, epochs: int) -> tuple[PointHeatmapNet, dict[str, Any]]:
    """The detector fitted on ``data`` and its report (train_detector's hook)."""
    from observer_gym.estimation.learned.heatmap_detector import fit_point_detector

    return fit_point_detector(data, seed, epochs)


def save(net: PointHeatmapNet, path: Path, report: dict[str, Any]) -> None:
    """Write the weights and their report (train_detector's hook)."""
    from observer_gym.estimation.learned.heatmap_detector import save_point_detector

    save_point_detector(net, CAMERA_PX, path, report)


class LearnedBallDetector:
    """The learned detector with the blob detector's interface
    (:class:`~observer_gym.estimation.ball_catcher.detector.BallCatcherDetector`):
    :meth:`detect` gives the ball's (u, v) or None.

    Args:
        path: the weight file (default :data:`WEIGHTS`); refused if changed.
        image_size_px: the env's camera image (width, height); refused unless the
            network's.
        owner: the observer's name, in error messages.
    """

    def __init__(
        self,
        path: Path | None = None,
        image_size_px: tuple[int, int] = CAMERA_PX,
        owner: str = "LearnedBallDetector",
    ) -> None:
        from observer_gym.estimation.learned.heatmap_detector import LearnedPointDetector

        self.network = LearnedPointDetector(Path(path) if path else WEIGHTS)
        self.network.check_camera(image_size_px, owner)
        self.last: PointDetection | None = None  # the last frame's detection

    def detect(self, image_rgb: np.ndarray) -> np.ndarray | None:
        """The ball's centre (u, v) in pixels, or None when the network finds it with a
        probability of 1/2 or less; the whole detection (with its variance) is kept in
        :attr:`last`."""
        detection = self.network.detect(image_rgb)
        self.last = detection
        return detection.uv_px.copy() if detection.detected else None
