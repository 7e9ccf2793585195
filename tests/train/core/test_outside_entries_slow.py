"""Outside entries, the long way: a package installed by pip with entry points, used by
the command in a fresh process; and the same records from Ray tasks as from local
workers."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import pytest
from outside_package import PACKAGE, VERSION, forget_package, write_package

import observer_gym

pytestmark = pytest.mark.slow

ENV = "BallTable-v0"
OBSERVER = f"{PACKAGE}.filters:make_observer-measurements"
CONTROLLER = f"{PACKAGE}.control:make_controller_"


def test_ray_tasks_give_the_records_of_local_workers(tmp_path, monkeypatch):
    pytest.importorskip("ray")
    root = write_package(tmp_path / "site")
    monkeypatch.syspath_prepend(str(root))  # Ray's private instance gets it as PYTHONPATH
    forget_package()
    common = {
        "seeds": [0, 1],
        "steps": 80,
        "observer_options": {"alpha": 0.6},
        "controller_options": {"gain": 0.9},
    }
    pairs = ([OBSERVER, "kf-measurements"], [CONTROLLER, "lqr"])
    local = observer_gym.compare(ENV, *pairs, workers=2, out_dir=tmp_path / "local", **common)
    ray = observer_gym.compare(ENV, *pairs, backend="ray", out_dir=tmp_path / "ray", **common)
    assert [p.episodes for p in local.pairs] == [p.episodes for p in ray.pairs]
    forget_package()


def test_a_pip_installed_package_is_found_by_its_entry_points(tmp_path):
    source = write_package(tmp_path / "src")
    (source / "pyproject.toml").write_text(
        textwrap.dedent(
            f"""
            [build-system]
            requires = ["setuptools>=61"]
            build-backend = "setuptools.build_meta"

            [project]
            name = "{PACKAGE}"
            version = "{VERSION}"

            [tool.setuptools]
            packages = ["{PACKAGE}"]

            [project.entry-points."observer_gym.observers"]
            alpha-beta = "{PACKAGE}.filters:make_observer"

            [project.entry-points."observer_gym.controllers"]
            scaled-lqr = "{PACKAGE}.control:make_controller_"
            """
        )
    )
    target = tmp_path / "installed"
    subprocess.run(
        [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation",
         "--target", str(target), str(source)],
        check=True,
    )  # fmt: skip
    env = {**os.environ, "PYTHONPATH": str(target)}  # a fresh process, the package installed
    command = [sys.executable, "-m", "observer_gym.train.cli"]
    listed = subprocess.run(
        [*command, "list", "controller"], env=env, capture_output=True, text=True, check=True
    ).stdout
    assert f"scaled-lqr  {PACKAGE}.control:make_controller_ ({VERSION})" in listed
    out = tmp_path / "run"
    subprocess.run(
        [*command, "run", "--env", ENV, "--observer", "alpha-beta-measurements",
         "--controller", "scaled-lqr", "--episodes", "2", "--workers", "2", "--steps", "40",
         "--out", str(out), "--no-progress"],
        env=env, check=True, capture_output=True,
    )  # fmt: skip
    config = json.loads((out / "results.json").read_text())["config"]
    assert config["entry"] == {
        "name": "alpha-beta-measurements",
        "import_path": f"{PACKAGE}.filters:make_observer",
        "source": f"entry point of {PACKAGE}",
        "package": PACKAGE,
        "version": VERSION,
        "options": {},
    }
