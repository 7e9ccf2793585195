"""Release hygiene (issue 28): the version users see is the installed metadata's, the
type marker and the licence ship with the package."""

import re
import sys
from importlib import metadata, resources
from pathlib import Path

import observer_gym

ROOT = Path(__file__).resolve().parent.parent


def test_version_is_the_installed_metadata():
    assert observer_gym.__version__ == metadata.version("observer-gym")


def test_version_is_pyprojects_and_has_a_changelog_entry():
    if sys.version_info >= (3, 11):
        import tomllib
    else:
        import tomli as tomllib
    with open(ROOT / "pyproject.toml", "rb") as f:
        version = tomllib.load(f)["project"]["version"]
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
