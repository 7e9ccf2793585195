"""Detectors: camera frames (or an env's perfect measurements) to measurements, one module
per scene."""

from observer_gym.estimation.detectors.ball_table import (
    BallTableDetection,
    BallTableDetector,
    BallTableFeatures,
    extract_features,
    features_from_measurement,
)

__all__ = [
    "BallTableDetection",
    "BallTableDetector",
    "BallTableFeatures",
    "extract_features",
    "features_from_measurement",
]
