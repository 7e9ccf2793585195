"""Camera geometry, detectors, Kalman filters, process models and the observer wrapper.

``VisionObserver(env)`` turns an env's camera frames into state estimates with the layout
of its ``obs_mode="state"`` observation; each system's observers are the ``OBSERVERS`` of
its package ``observer_gym.estimation.<system>``.
"""

from observer_gym.estimation.observer import (
    Estimate,
    VisionObserver,
    default_pipeline,
    observers_of,
    observers_of_system,
)

__all__ = ["Estimate", "VisionObserver", "default_pipeline", "observers_of", "observers_of_system"]
