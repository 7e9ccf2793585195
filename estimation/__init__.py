"""Camera geometry, detectors, Kalman filters and the observer wrapper (to come)."""
