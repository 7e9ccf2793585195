"""Learned observers: a network trained on the simulator's truth that maps the newest
frames' detections to the state estimate and its covariance.

``network.py`` the Gaussian network and its weight files (checked by their sha256),
``training.py`` the Gaussian negative log-likelihood fit and its held-out report,
``inputs.py`` which obs modes a learned observer reads. From rendered frames a learned
detector reads each frame in the perfect detector's place: ``frame_detector.py`` the
Gaussian CNN and its weight files, ``frame_training.py`` its fit and held-out report;
``heatmap_detector.py`` a fully convolutional detector of one small point read at full
resolution (BallCatcher's ball), with its fit, report and weight files. Each system's
features and observer live in its own package (``estimation/<system>/learned.py``,
``learned_detector.py``), its shipped weights beside them. Collecting the training data
(a controller runs the episodes) and the training commands are experiments, in
``observer_gym.train.experiments.learned_observers``::

    python -m observer_gym.train.experiments.learned_observers.train --env ENV
    python -m observer_gym.train.experiments.learned_observers.train_detector --env ENV

Nothing here imports the controllers or ``observer_gym.train`` (tests/test_layers.py).

Torch is imported by these modules only, so ``import observer_gym.estimation`` does not
load it.
"""
