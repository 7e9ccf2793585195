"""Finds the packages of pyproject.toml's package-dir (envs/ is observer_gym.envs, ...).

Why a setup.py: [tool.setuptools.packages.find] names what it finds after the folder it
searches (envs.robots), it cannot put the mapped name in front (observer_gym.envs.robots).
Everything else is declared in pyproject.toml.
"""

import sys
from pathlib import Path

from setuptools import find_namespace_packages, setup

if sys.version_info >= (3, 11):
    import tomllib
else:  # Python 3.10: pyproject's build-system requires tomli there
    import tomli as tomllib

ROOT = Path(__file__).resolve().parent


def packages(package_dir: dict[str, str]) -> list[str]:
    """Every importable folder under each mapped folder: the ones with an __init__.py and
    the data-only ones (envs/assets/, ...: PEP 420 namespace packages, each shipping its
    package-data). Not the agents' run folders (agents/<name>-<obs>/ is no identifier),
    which ship as agents' package-data."""
    found = set(package_dir)
    for package, folder in package_dir.items():
        for name in find_namespace_packages(ROOT / folder, exclude=["*__pycache__*"]):
            if all(part.isidentifier() for part in name.split(".")):
                found.add(f"{package}.{name}")
    return sorted(found)


with open(ROOT / "pyproject.toml", "rb") as f:
    setup(packages=packages(tomllib.load(f)["tool"]["setuptools"]["package-dir"]))
