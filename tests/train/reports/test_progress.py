"""reports/progress.py: a terminal that reports no size (0 x 0) still gets a bar."""

from __future__ import annotations

import os

from observer_gym.train.reports import progress


def test_a_terminal_of_no_size_gets_one(monkeypatch):
    monkeypatch.setattr(progress.os, "get_terminal_size", lambda fd=None: os.terminal_size((0, 0)))
    monkeypatch.setenv("COLUMNS", "90")
    monkeypatch.setenv("LINES", "30")
    assert progress.terminal_shape() == {"ncols": 90, "nrows": 30}
    monkeypatch.setattr(
        progress.os, "get_terminal_size", lambda fd=None: os.terminal_size((120, 40))
    )
    assert progress.terminal_shape() == {}  # tqdm reads a real size itself


def test_no_terminal_leaves_tqdm_alone(monkeypatch):
    def no_terminal(fd=None):
        raise OSError("not a terminal")

    monkeypatch.setattr(progress.os, "get_terminal_size", no_terminal)
    assert progress.terminal_shape() == {}
