"""Release hygiene (issue 28): the version users see is the installed metadata's, the
type marker and the licence ship with the package; (issue 42) the wheel holds every
package of the source tree and its data."""

import re
import shutil
import subprocess
import sys
import zipfile
from importlib import metadata, resources
from pathlib import Path

import pytest

import observer_gym

ROOT = Path(__file__).resolve().parent.parent


def test_version_is_the_installed_metadata():
    assert observer_gym.__version__ == metadata.version("observer-gym")


def pyproject() -> dict:
    if sys.version_info >= (3, 11):
        import tomllib
    else:
        import tomli as tomllib
    with open(ROOT / "pyproject.toml", "rb") as f:
        return tomllib.load(f)


def test_version_is_pyprojects_and_has_a_changelog_entry():
    version = pyproject()["project"]["version"]
    assert observer_gym.__version__ == version  # reinstall after changing the version
    changelog = (ROOT / "CHANGELOG.md").read_text()
    assert re.search(rf"^## \[{re.escape(version)}\] - \d{{4}}-\d{{2}}-\d{{2}}$", changelog, re.M)


def test_py_typed_marker_at_the_top_package():
    assert resources.files("observer_gym").joinpath("py.typed").is_file()


def test_license_is_mit_and_declared():
    text = (ROOT / "LICENSE").read_text()
    assert text.startswith("MIT License")
    assert "observer-gym developers" in text
    assert metadata.metadata("observer-gym")["License-Expression"] == "MIT"


# The package data, by kind: each kind must match files in the source tree (or the
# check would pass on nothing) and every match must be in the wheel.
PACKAGE_DATA = {
    "the type marker": "observer_gym/py.typed",
    "the URDFs": "envs/assets/*.urdf",
    "the observers' and detectors' weights": "estimation/**/*.pt",
    "their reports": "estimation/**/*.json",
    "the benchmark suites": "train/experiments/benchmark/suites/*/*.json",
    "the shipped agents' files": "train/rl/agents/*/*",
    "the pixel encoders": "train/rl/encoders/*",
    "the hyperparameters": "train/rl/hyperparams/**/*.yml",
}


@pytest.mark.slow  # builds the wheel (4 s); CI's plain-install step builds and installs it too
def test_the_wheel_holds_every_package_and_its_data(tmp_path):
    """A plain `pip install .` installs the wheel: every source folder with an __init__.py
    is in it as its mapped package (envs/robots/ as observer_gym/envs/robots/), with its
    modules, and so is every package-data file."""
    pytest.importorskip("setuptools", minversion="77")  # the build backend, used in place
    config = pyproject()
    package_dir = config["tool"]["setuptools"]["package-dir"]  # package -> source folder
    folders = {folder: package.replace(".", "/") for package, folder in package_dir.items()}
    assert {init.parent.name for init in ROOT.glob("*/__init__.py")} == set(folders)

    # Built from a copy of what the build reads: in place, setuptools would also ship the
    # leftovers of an earlier build in ./build/lib.
    source = tmp_path / "source"
    for folder in folders:
        shutil.copytree(
            ROOT / folder, source / folder, ignore=shutil.ignore_patterns("__pycache__")
        )
    readme, licenses = config["project"]["readme"], config["project"]["license-files"]
    for name in ["pyproject.toml", "setup.py", readme, *licenses]:
        shutil.copy2(ROOT / name, source / name)
    pip_wheel = [sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "--no-index"]
    pip_wheel += ["--no-build-isolation", "--wheel-dir", str(tmp_path / "dist"), str(source)]
    subprocess.run(pip_wheel, check=True)
    [wheel] = (tmp_path / "dist").glob("*.whl")
    with zipfile.ZipFile(wheel) as archive:
        in_wheel = set(archive.namelist())

    def installed(path: Path) -> str:
        folder, *rest = path.relative_to(ROOT).parts
        return "/".join([folders[folder], *rest])

    expected = {}
    for folder in folders:
        for init in (ROOT / folder).rglob("__init__.py"):
            if "__pycache__" not in init.parts:
                for module in init.parent.glob("*.py"):
                    expected[module] = "a package's module"
    for kind, pattern in PACKAGE_DATA.items():
        files = [
            path
            for path in ROOT.glob(pattern)
            if path.is_file() and "__pycache__" not in path.parts
        ]
        assert files, f"{kind}: no {pattern} in the source tree"
        expected.update(dict.fromkeys(files, kind))
    missing = sorted(
        f"{installed(path)} ({kind})"
        for path, kind in expected.items()
        if installed(path) not in in_wheel
    )
    assert not missing, "not in the wheel:\n" + "\n".join(missing)
