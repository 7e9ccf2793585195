"""Camera geometry, detectors, Kalman filters, process models and the observer wrapper.

``VisionObserver(env)`` turns an env's camera frames into state estimates with the layout
of its ``obs_mode="state"`` observation.
"""

from observer_gym.estimation.observer import Estimate, VisionObserver, default_pipeline

__all__ = ["Estimate", "VisionObserver", "default_pipeline"]
