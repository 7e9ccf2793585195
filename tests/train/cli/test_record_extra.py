"""``observer-gym record`` without its extra: one line naming the missing module and the
install line, exit code 2, nothing written. Runs whether or not minari is installed (each
module of the extra is hidden in turn)."""

from __future__ import annotations

import importlib.util
import sys

import pytest

from observer_gym.train.cli import main

ARGV = ["record", "--observer", "kf-measurements", "--controller", "lqr", "--episodes", "1"]


@pytest.mark.parametrize("module", ["minari", "jax", "h5py"])
def test_record_without_the_extra_names_the_install_line(module, tmp_path, capsys, monkeypatch):
    real = importlib.util.find_spec

    def find_spec(name, *args, **kwargs):
        return None if name == module else real(name, *args, **kwargs)

    monkeypatch.delitem(sys.modules, module, raising=False)
    monkeypatch.setattr(importlib.util, "find_spec", find_spec)
    code = main([*ARGV, "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert code == 2
    assert len(err.strip().splitlines()) == 1, err
    assert f"observer-gym record needs {module}, which is not installed: " in err
    assert "pip install 'observer-gym[record]'" in err
    assert not (tmp_path / "r").exists()
