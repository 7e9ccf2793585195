"""mypy on the package as it installs (`make typecheck`, CI's type-check step).

The source folders map to observer_gym.* (pyproject's package-dir: envs/ is
observer_gym.envs, ...), a layout mypy cannot read from the folders themselves nor from
the editable install's import hook. So this links the installed layout in
build/typecheck/ (observer_gym/envs -> envs/, ...), runs `mypy -p observer_gym` there
with pyproject's [tool.mypy] and prints mypy's report with the source folders' paths.
Exits with mypy's status.
"""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10: mypy itself depends on tomli there
    import tomli as tomllib

from mypy import api

ROOT = Path(__file__).resolve().parent.parent
TREE = ROOT / "build" / "typecheck"


def package_dirs() -> dict[str, str]:
    """pyproject's package-dir: package name -> source folder (relative to the root)."""
    with open(ROOT / "pyproject.toml", "rb") as f:
        return tomllib.load(f)["tool"]["setuptools"]["package-dir"]


def link_tree(mapping: dict[str, str]) -> None:
    """build/typecheck/<the package's path> -> its source folder, for each mapped package;
    the top-level package is a folder of links (its subpackages live elsewhere)."""
    shutil.rmtree(TREE / "observer_gym", ignore_errors=True)
    top = TREE / "observer_gym"
    top.mkdir(parents=True)
    for entry in (ROOT / mapping["observer_gym"]).iterdir():
        if entry.name != "__pycache__":
            (top / entry.name).symlink_to(entry)
    for package, folder in mapping.items():
        if package != "observer_gym":
            (TREE / package.replace(".", "/")).symlink_to(ROOT / folder)


def main() -> int:
    mapping = package_dirs()
    link_tree(mapping)
    os.chdir(TREE)
    args = ["--config-file", str(ROOT / "pyproject.toml")]
    args += ["--cache-dir", str(ROOT / ".mypy_cache"), "-p", "observer_gym", *sys.argv[1:]]
    stdout, stderr, status = api.run(args)
    # observer_gym/envs/core.py -> envs/core.py: the longest package path first
    prefixes = sorted(
        (
            (package.replace(".", "/") + "/", folder.rstrip("/") + "/")
            for package, folder in mapping.items()
        ),
        key=lambda pair: -len(pair[0]),
    )
    for line in stdout.splitlines():
        for installed, source in prefixes:
            if line.startswith(installed):
                line = source + line[len(installed) :]
                break
        print(line)
    sys.stderr.write(stderr)
    return status


if __name__ == "__main__":
    sys.exit(main())
