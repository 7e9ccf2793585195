"""The ``>>>`` examples in the public docstrings run and print what they say.

Every example in the package's modules is collected (a new one runs without an edit here),
and the public entry points named in ``REQUIRED`` must each have one: the envs,
``VisionObserver``, ``make_controller``, the Python API and the public wrappers.
"""

from __future__ import annotations

import doctest
import importlib
import pkgutil

import pytest

PACKAGES = ("envs", "estimation", "controllers", "train", "wrappers")

REQUIRED = (
    "observer_gym.envs.ball_table.env.BallTableEnv",
    "observer_gym.envs.ball_catcher.env.BallCatcherEnv",
    "observer_gym.envs.target_follower.env.TargetFollowerEnv",
    "observer_gym.estimation.observer.VisionObserver",
    "observer_gym.controllers.registry.make_controller",
    "observer_gym.train.experiments.api.run",
    "observer_gym.train.experiments.api.compare",
    "observer_gym.train.experiments.api.sweep",
    "observer_gym.train.experiments.api.evaluate",
    "observer_gym.wrappers.frames.FrameImages",
    "observer_gym.wrappers.frames.GrayFrameStack",
    "observer_gym.wrappers.flat.FlatObservation",
    "observer_gym.wrappers.actions.NormalizedAction",
)

FLAGS = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE


def _modules() -> list[str]:
    names = ["observer_gym"]
    for package in PACKAGES:
        module = importlib.import_module(f"observer_gym.{package}")
        names.append(module.__name__)
        names += [
            info.name
            for info in pkgutil.walk_packages(module.__path__, prefix=f"{module.__name__}.")
            if not info.name.endswith("__main__")
        ]
    return names


def _examples() -> dict[str, doctest.DocTest]:
    finder = doctest.DocTestFinder(exclude_empty=True)
    found = {}
    for name in _modules():
        module = importlib.import_module(name)
        for test in finder.find(module, name, globs={}):
            if test.examples:
                found[test.name] = test
    return found


EXAMPLES = _examples()


def test_every_public_entry_point_has_an_example():
    missing = [name for name in REQUIRED if name not in EXAMPLES]
    assert not missing, f"no >>> example in the docstring of {missing}"


# the compare's and the sweep's examples run several episodes (2.8 s and 1.3 s idle): slow; the
# examples of run and evaluate, which run episodes too, stay in the default run
SLOW_EXAMPLES = {
    "observer_gym.train.experiments.api.compare",
    "observer_gym.train.experiments.api.sweep",
}


@pytest.mark.parametrize(
    "name",
    [
        pytest.param(name, marks=pytest.mark.slow) if name in SLOW_EXAMPLES else name
        for name in sorted(EXAMPLES)
    ],
)
def test_example_runs(name, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # an example that writes a file writes it here
    test = EXAMPLES[name]
    runner = doctest.DocTestRunner(optionflags=FLAGS)
    output: list[str] = []
    runner.run(test, out=output.append)
    assert runner.failures == 0, "".join(output)
