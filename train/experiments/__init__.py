"""The experiments: run, compare, sweep, evaluate, the consistency study, the
papers' studies (reproduce/), the tasks per system (tasks/), the entries from outside
the package and the backends (worker processes, Ray).
"""
