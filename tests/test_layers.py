"""The layers' one direction (docs/architecture.md): nothing in ``observer_gym.estimation``
imports the controllers or ``observer_gym.train``, and nothing in ``observer_gym.envs``
imports the estimation, the controllers or ``observer_gym.train``.

Read from the source with :mod:`ast`, not by importing it, so an import deferred into a
function (the kind that runs only when that function does), a relative one
(``from ...controllers import x``) and an ``importlib.import_module("...")`` of a literal
name all count. Collecting a learned observer's training data with a controller is an
experiment: it lives in ``observer_gym.train.experiments.learned_observers``.
"""

from __future__ import annotations

import ast
import importlib.util
from pathlib import Path

import pytest

import observer_gym.envs
import observer_gym.estimation

# layer -> the packages it must not import (nor any module under them)
FORBIDDEN = {
    "observer_gym.estimation": ("observer_gym.controllers", "observer_gym.train"),
    "observer_gym.envs": (
        "observer_gym.estimation",
        "observer_gym.controllers",
        "observer_gym.train",
    ),
}
ROOTS = {
    "observer_gym.estimation": Path(observer_gym.estimation.__file__).parent,
    "observer_gym.envs": Path(observer_gym.envs.__file__).parent,
}
IMPORTERS = {"import_module", "__import__"}


def _modules(package: str) -> dict[str, Path]:
    """{module name: its file} for every module of ``package``, its __init__ files included."""
    root = ROOTS[package]
    modules = {}
    for path in sorted(root.rglob("*.py")):
        parts = path.relative_to(root).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        modules[".".join((package, *parts))] = path
    return modules


def imported_names(source: str, module: str, is_package: bool) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in ``source``, wherever it stands
    (module level, in a function or a class, under ``if TYPE_CHECKING``): ``import a.b``,
    ``from a import b`` (as ``a`` and ``a.b``), relative imports resolved against
    ``module``, and ``importlib.import_module`` / ``__import__`` of a literal string."""
    package = module if is_package else module.rpartition(".")[0]
    found: list[tuple[int, str]] = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = importlib.util.resolve_name("." * node.level + (node.module or ""), package)
            found.append((node.lineno, base))
            found += [(node.lineno, f"{base}.{alias.name}") for alias in node.names]
        elif isinstance(node, ast.Call) and node.args:
            called = node.func
            name = called.attr if isinstance(called, ast.Attribute) else getattr(called, "id", "")
            first = node.args[0]
            if (
                name in IMPORTERS
                and isinstance(first, ast.Constant)
                and isinstance(first.value, str)
            ):
                found.append((node.lineno, first.value))
    return found


def upward_imports(source: str, module: str, is_package: bool, forbidden: tuple[str, ...]):
    """The imports of ``source`` that name a module under one of ``forbidden``."""
    return [
        f"line {line}: {name}"
        for line, name in imported_names(source, module, is_package)
        if any(name == top or name.startswith(f"{top}.") for top in forbidden)
    ]


CASES = [(layer, module, path) for layer in FORBIDDEN for module, path in _modules(layer).items()]


def test_every_module_of_both_layers_is_read():
    names = {module for _, module, _ in CASES}
    # the learned observers and the base env, which once imported upward, are among them
    assert {
        "observer_gym.estimation.ball_table.learned",
        "observer_gym.estimation.learned",
        "observer_gym.estimation.learned.network",
        "observer_gym.envs.core",
    } <= names
    assert len(names) > 100


@pytest.mark.parametrize(("layer", "module", "path"), CASES, ids=[module for _, module, _ in CASES])
def test_no_module_imports_a_higher_layer(layer, module, path):
    source = path.read_text(encoding="utf-8")
    found = upward_imports(source, module, path.name == "__init__.py", FORBIDDEN[layer])
    assert not found, f"{path} imports above its layer ({layer}): {found}"


# the checker itself: each way an upward import can be written is found
@pytest.mark.parametrize(
    "source",
    [
        "import observer_gym.controllers\n",
        "from observer_gym.controllers import make_controller\n",
        "from observer_gym import train\n",
        "def collect():\n    from observer_gym.controllers import make_controller\n",
        "class A:\n    def f(self):\n        import observer_gym.train.cli.args as args\n",
        "from ...controllers import make_controller\n",
        "from ... import controllers\n",
        "from ...train.cli.args import Parser\n",
        "import importlib\nimportlib.import_module('observer_gym.controllers.ball_table')\n",
        "__import__('observer_gym.train')\n",
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import observer_gym.train\n",
    ],
)
def test_the_check_finds_an_upward_import_however_it_is_written(source):
    forbidden = FORBIDDEN["observer_gym.estimation"]
    found = upward_imports(source, "observer_gym.estimation.ball_table.learned", False, forbidden)
    assert len(found) >= 1, source


@pytest.mark.parametrize(
    "source",
    [
        "from observer_gym.estimation.learned.network import load_network\n",
        "from ..learned.inputs import require_frames_or_measurements\n",
        "from observer_gym.envs.ball_table import STATE_DIM\n",
        "import importlib\nimportlib.import_module(name)\n",  # not a literal: not read
        "# from observer_gym.controllers import make_controller\n",
        "'''python -m observer_gym.train.experiments.learned_observers.train'''\n",
    ],
)
def test_the_check_passes_imports_of_the_layer_itself_and_below(source):
    forbidden = FORBIDDEN["observer_gym.estimation"]
    assert (
        upward_imports(source, "observer_gym.estimation.ball_table.learned", False, forbidden) == []
    )


def test_a_relative_import_resolves_from_the_package_its_file_stands_in():
    forbidden = FORBIDDEN["observer_gym.estimation"]
    source = "from ..controllers import make_controller\n"
    # in estimation/filters.py ".." is observer_gym: observer_gym.controllers
    assert upward_imports(source, "observer_gym.estimation.filters", False, forbidden) == [
        "line 1: observer_gym.controllers",
        "line 1: observer_gym.controllers.make_controller",
    ]
    # in estimation/ball_table/__init__.py ".." is observer_gym.estimation
    assert upward_imports(source, "observer_gym.estimation.ball_table", True, forbidden) == []
