"""The learned observers' training: experiments that run a system's controller to collect
the data, and the commands that fit the networks on it and write their weights.

``ball_table.py``, ``target_follower.py``, ``ball_catcher.py`` each system's
collection: ``collect`` (the ``learned`` network's features and the truth, the
controller on the truth or, a DAgger round, on a network's estimate: its episodes
recorded as a Minari dataset by ``record_episodes`` and read back by ``recorded.py``,
the one reader of recorded training data) and ``collect_frames`` (the learned detector's
frames and labels, with ``frame_data.py``'s lockstep episodes, kept in memory).
``train.py`` and ``train_detector.py`` the commands::

    python -m observer_gym.train.experiments.learned_observers.train --env ENV
    python -m observer_gym.train.experiments.learned_observers.train_detector --env ENV

The networks, their fits, the shipped weights and the observers that run them are in
``observer_gym.estimation`` (``estimation/learned/``, ``estimation/<system>/learned*.py``),
which imports nothing of this package nor of the controllers.
"""
