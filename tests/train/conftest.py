"""Fixtures shared by the tests of train/: the outside package of outside_package.py on
the path."""

from __future__ import annotations

import pytest
from outside_package import forget_package, write_package


@pytest.fixture
def outside(tmp_path, monkeypatch):
    """The outside package on sys.path (this process and the workers it spawns)."""
    root = write_package(tmp_path / "site")
    monkeypatch.syspath_prepend(str(root))
    forget_package()
    yield root
    forget_package()
