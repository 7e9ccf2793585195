"""Every module of observer_gym.train imports alone in a fresh interpreter, and no two
modules of the package import each other, even through functions (no import cycle).

The imports run in one subprocess (tests/train/fresh_imports.py), each in its own child
forked from a process that has imported nothing of observer-gym: one interpreter start-up
and one load of the third-party libraries instead of one per module."""

from __future__ import annotations

import ast
import json
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest

import observer_gym.train

PACKAGE = "observer_gym.train"
ROOT = Path(observer_gym.train.__file__).parent


def _modules() -> dict[str, Path]:
    modules = {}
    for info in pkgutil.walk_packages([str(ROOT)], prefix=f"{PACKAGE}."):
        relative = info.name.removeprefix(f"{PACKAGE}.").replace(".", "/")
        path = ROOT / (f"{relative}/__init__.py" if info.ispkg else f"{relative}.py")
        modules[info.name] = path
    return modules


MODULES = _modules()


@pytest.fixture(scope="module")
def imported_alone() -> dict[str, str | None]:
    """{module: the traceback of importing it alone, or None}, for every module."""
    script = Path(__file__).with_name("fresh_imports.py")
    result = subprocess.run(
        [sys.executable, str(script), "modules", *sorted(MODULES)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)


@pytest.mark.slow  # a forked child per module (17 s idle); test_no_import_cycle below
# (static, 0.4 s) finds the cycles that break an import alone, in the default run
@pytest.mark.parametrize("module", sorted(MODULES))
def test_each_module_imports_alone(module, imported_alone):
    assert imported_alone[module] is None, imported_alone[module]


def _imported(path: Path, module: str) -> set[str]:
    """The modules of the package that ``module`` imports anywhere in its code."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
            names |= {f"{node.module}.{alias.name}" for alias in node.names}
    return {name for name in names if name in MODULES and name != module}


def test_no_import_cycle():
    graph = {module: _imported(path, module) for module, path in MODULES.items()}
    done: set[str] = set()

    def visit(module: str, path: list[str]) -> None:
        if module in path:
            cycle = [*path[path.index(module) :], module]
            pytest.fail(f"import cycle: {' -> '.join(cycle)}")
        if module in done:
            return
        for imported in sorted(graph[module]):
            visit(imported, [*path, module])
        done.add(module)

    for module in sorted(graph):
        visit(module, [])
