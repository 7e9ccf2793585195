"""``run --rerun`` without its extra: one line naming rerun-sdk and the install line, exit
code 2, nothing written. Runs whether or not rerun-sdk is installed (it is hidden)."""

from __future__ import annotations

import importlib.util
import sys

from observer_gym.train.cli import main

ARGV = ["run", "--observer", "kf", "--controller", "lqr", "--episodes", "1", "--steps", "5"]


def test_rerun_without_the_extra_names_the_install_line(tmp_path, capsys, monkeypatch):
    real = importlib.util.find_spec

    def find_spec(name, *args, **kwargs):
        return None if name == "rerun" else real(name, *args, **kwargs)

    monkeypatch.delitem(sys.modules, "rerun", raising=False)
    monkeypatch.setattr(importlib.util, "find_spec", find_spec)
    rrd = tmp_path / "x.rrd"
    code = main([*ARGV, "--out", str(tmp_path / "r"), "--rerun", str(rrd)])
    err = capsys.readouterr().err
    assert code == 2
    assert len(err.strip().splitlines()) == 1, err
    assert "--rerun needs rerun-sdk, which is not installed: " in err
    assert "pip install 'observer-gym[rerun]'" in err
    assert not (tmp_path / "r").exists() and not rrd.exists()


def test_the_library_refuses_it_too(tmp_path, monkeypatch):
    import pytest

    from observer_gym.extras import ExtraNotInstalled
    from observer_gym.train.experiments.api import run

    real = importlib.util.find_spec
    monkeypatch.delitem(sys.modules, "rerun", raising=False)
    monkeypatch.setattr(
        importlib.util,
        "find_spec",
        lambda name, *a, **k: None if name == "rerun" else real(name, *a, **k),
    )
    with pytest.raises(ExtraNotInstalled, match=r"observer-gym\[rerun\]"):
        run("BallTable-v0", "kf", "lqr", episodes=1, steps=5, out_dir=tmp_path / "r",
            rerun_file=tmp_path / "x.rrd")  # fmt: skip
    assert not (tmp_path / "r").exists() and not (tmp_path / "x.rrd").exists()
