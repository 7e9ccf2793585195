"""Learned observers: a network trained on the simulator's truth that maps the newest
frames' detections to the state estimate and its covariance.

``network.py`` the Gaussian network and its weight files (checked by their sha256),
``training.py`` the Gaussian negative log-likelihood fit and its held-out report,
``inputs.py`` the measurements-only check every learned observer makes; each
system's features and observer live in its own package (``estimation/<system>/learned.py``),
its shipped weights beside them. Train with
``python -m observer_gym.estimation.learned.train --env ENV``.

Torch is imported by these modules only, so ``import observer_gym.estimation`` does not
load it.
"""
