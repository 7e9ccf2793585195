"""The floor of ``observer_gym.train``: what the command line, the experiments, the
training and the reports all stand on. Systems and their tasks, observers and
controllers from outside (entries and their guard), the env an observer reads
(``make_env``), the up-front checks of a request and the argument types of every command
line. Nothing here imports ``cli``, ``experiments``, ``rl`` or ``reports``.
"""
