"""The packages of ``observer_gym.train`` stand on one another in one direction:
cli -> experiments -> rl -> reports -> core. No module of a lower package imports a
higher one, at the top of the file or inside a function (docs/architecture.md).

Read from the source with :mod:`ast`; nothing is imported."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import observer_gym.train

PACKAGE = "observer_gym.train"
ROOT = Path(observer_gym.train.__file__).parent
# lowest first: a package may import its own modules and those of the packages before it
LAYERS = ("core", "reports", "rl", "experiments", "cli")
RANK = {name: rank for rank, name in enumerate(LAYERS)}

# Upward imports not yet removed, each (importing module, imported module): none is left.
# A new upward import fails the test; it is removed by moving code down, not listed here.
KNOWN_UPWARD: set[tuple[str, str]] = set()


def _module_name(path: Path) -> str:
    parts = [PACKAGE, *path.relative_to(ROOT).with_suffix("").parts]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _layer(module: str) -> str | None:
    parts = module.split(".")
    return parts[2] if len(parts) > 2 and parts[2] in RANK else None


def _is_module(name: str) -> bool:
    relative = Path(*name.split(".")[2:])
    return (ROOT / relative).with_suffix(".py").is_file() or (ROOT / relative).is_dir()


def imports_of(path: Path) -> set[str]:
    """Every module of the package that ``path`` imports, anywhere in its code (relative
    imports resolved; ``from package import module`` counts the module)."""
    module = _module_name(path)
    package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join([*package[: len(package) - node.level + 1], *filter(None, [base])])
            found.add(base)
            found.update(
                f"{base}.{alias.name}" for alias in node.names if _is_module(f"{base}.{alias.name}")
            )
    return {name for name in found if name.startswith(f"{PACKAGE}.")}


def upward_imports(root: Path = ROOT) -> set[tuple[str, str]]:
    """(importer, imported) for every import from a lower layer of ``root`` to a higher one."""
    upward = set()
    for path in sorted(root.rglob("*.py")):
        importer = _module_name(path)
        low = _layer(importer)
        if low is None:
            continue
        for imported in imports_of(path):
            high = _layer(imported)
            if high is not None and RANK[high] > RANK[low]:
                upward.add((importer, imported))
    return upward


def test_every_package_of_train_is_a_layer():
    packages = {p.name for p in ROOT.iterdir() if (p / "__init__.py").is_file()}
    assert packages == set(LAYERS)


def test_no_lower_package_imports_a_higher_one():
    upward = upward_imports()
    new = sorted(upward - KNOWN_UPWARD)
    assert not new, "imports from a lower package of observer_gym.train to a higher one:\n" + (
        "\n".join(f"{a} -> {b}" for a, b in new)
    )
    gone = sorted(KNOWN_UPWARD - upward)
    assert not gone, f"no longer imported, drop from KNOWN_UPWARD: {gone}"


@pytest.mark.parametrize(
    ("source", "expected"),
    [
        ("from observer_gym.train.cli.args import Parser\n", True),
        ("def f():\n    from observer_gym.train.experiments import request\n", True),
        ("from ..experiments.request import check_pair\n", True),
        ("import observer_gym.train.rl.hyperparams\n", True),
        ("from observer_gym.train.core.args import Parser\n", False),
        ("from . import entries\n", False),
    ],
)
def test_the_check_sees_an_upward_import(tmp_path, monkeypatch, source, expected):
    """The check itself: a core module that imports cli, experiments or rl (absolute,
    relative or deferred) is found; one that imports core is not."""
    root = tmp_path / "train"
    for layer in LAYERS:
        (root / layer).mkdir(parents=True)
        (root / layer / "__init__.py").write_text("")
    (root / "core" / "low.py").write_text(source)
    monkeypatch.setattr(f"{__name__}.ROOT", root)
    assert bool(upward_imports(root)) is expected
