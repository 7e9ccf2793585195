"""The BallTable detector: docs/spec/table_ball.md's "Vision pipeline" in OpenCV, in two
stages, and the names the rest of the package uses from it.

1. Image stage (pixels -> :class:`BallTableFeatures`): the red top's four corners (table
   steps 1-4 and the ordering of step 5) and the ball's image circle (ball step 1).
   :func:`extract_features` runs it on one frame, :class:`TableTracker` on the frames of
   one camera in order, with the table's region of interest tracked between frames.
2. Geometry stage, :class:`BallTableDetector` (features + calibration ->
   :class:`BallTableDetection`): PnP for the table's pose (table step 5), then the ball's
   position on the table (ball steps 2-4).

The measurements obs_mode already reports perfect features; :func:`features_from_measurement`
converts them, so the same geometry stage runs on both.

The modules of estimation/ball_table/ that hold the stages, in the order a frame meets
them:

- ``region.py``: the region of interest around the table and the ball's window (a
  coarse look at every 4th pixel);
- ``masks.py``: blur, HLS, the red and dark masks, the outlines (table steps 1-2);
- ``ball_image.py``: the ball's image circle (ball step 1);
- ``corners.py``: an outline's corners, sub-pixel, named and checked (table steps 2-5);
- ``image_stage.py``: the image stage in a region of interest, :func:`extract_features`;
- ``tracker.py``: :class:`TableTracker`;
- ``geometry_stage.py``: :class:`BallTableDetector`;
- ``features.py``: the records the stages hand each other;
- ``scale.py``: the frame's focal length relative to the spec's camera's.

Beyond the spec (each module's docstring gives the details and numbers, measured on 155
rendered 320x240 frames in tests/estimation/test_ball_table_detector.py): sub-pixel
corners; the borders' outer outline found beside the red top and the pose solved on all 8
corners (tilt RMSE 2.8 mrad against 12.4 for the red top alone); the ball's centre as its
blob's centroid on raw pixels. Never silently wrong: an outline touching the image's edge,
sides without a black border along them, corners that are no square or disagree with the
outline, an implausible pose (tilt > 0.35 rad, yaw > 0.1 rad), one square alone too small
in the image to pin the tilt, a ball cut in parts, filling its circle badly, or whose image
size does not fit its distance: each gives "not found" with a reason
(``BallTableFeatures.table_failure``, ``BallTableDetection.failure``).

Frame sizes: the pixel constants were set at the spec's 320x240 (90 deg, focal length
160 px); those that stand for sizes in the scene follow the focal length (``scale.py``),
so the detector also works down to the RL policies' 84 x 84 (focal length 42 px): ball
2.1 mm, tilt 16 and 5 mrad RMSE on rendered frames
(tests/estimation/test_ball_table_small_frames.py, which holds the table per size; command
``python benchmarks/quality_ball_table_sizes.py``). Below that the ball's image, ~2.5 px
in radius at 84 x 84, runs out of pixels (at 64 x 64 a third of the frames lose it).

Cost: ``python benchmarks/bench_detector.py`` times it against a bare OpenCV pass over the
whole frame (figures in the README).
"""

from __future__ import annotations

from observer_gym.estimation.ball_table.features import (
    BORDER_OUTLINE,
    RED_TOP,
    BallTableDetection,
    BallTableFeatures,
    features_from_measurement,
)
from observer_gym.estimation.ball_table.geometry_stage import BallTableDetector
from observer_gym.estimation.ball_table.image_stage import extract_features
from observer_gym.estimation.ball_table.tracker import TableTracker

__all__ = [
    "BORDER_OUTLINE",
    "RED_TOP",
    "BallTableDetection",
    "BallTableDetector",
    "BallTableFeatures",
    "TableTracker",
    "extract_features",
    "features_from_measurement",
]
