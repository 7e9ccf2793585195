"""The core install (``pip install observer-gym``, no PyTorch): what it runs, and what it
refuses in one line naming ``pip install 'observer-gym[rl]'``.

One fresh interpreter stands for that install: an import hook first in ``sys.meta_path``
makes torch, stable_baselines3, sb3_contrib and rl_zoo3 impossible to import (as if not
installed) and records every attempt to import them, so the checks below also show that
nothing the core commands reach even tries (asking whether a module is installed,
``importlib.util.find_spec``, is not an attempt). In it: every env makes and steps in
every observation mode, ``observer-gym list`` (the [rl] entries marked), a classical
``compare``, a short ``demo``; ``train``, ``evaluate``, a learned observer, a trained
agent, a stable-baselines3 zip each give one line on stderr and exit code 2 before any
env; the Python API raises :class:`observer_gym.extras.ExtraNotInstalled` (an
ImportError) naming the install line, and so does importing the training module. CI's
plain-install step (.ci/run) checks the built wheel in a venv where torch is absent.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import pytest

from observer_gym.extras import RL_INSTALL

# one child interpreter runs every env, a compare and the demo (5.5 s idle): the slow step;
# CI's plain-install step (.ci/run) checks the built wheel in a venv without torch
pytestmark = pytest.mark.slow

# run in the child: block the [rl] modules, then the checks; prints one JSON line
CHILD = textwrap.dedent(
    """
    import sys

    BLOCKED = {"torch", "stable_baselines3", "sb3_contrib", "rl_zoo3"}
    ATTEMPTS = []


    class Block:
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] not in BLOCKED:
                return None
            frame, asked = sys._getframe(1), False
            for _ in range(4):  # importlib.util.find_spec asks without importing
                if frame is None:
                    break
                code = frame.f_code
                where = code.co_filename  # importlib/util.py, or <frozen importlib.util>
                asked |= code.co_name == "find_spec" and "importlib" in where and "util" in where
                frame = frame.f_back
            if not asked:
                ATTEMPTS.append(name)
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)


    sys.meta_path.insert(0, Block())

    import contextlib
    import io
    import json
    from pathlib import Path

    import gymnasium as gym
    import numpy as np

    import observer_gym
    from observer_gym.envs import ENV_IDS
    from observer_gym.estimation import VisionObserver
    from observer_gym.extras import ExtraNotInstalled
    from observer_gym.train.cli import main

    out = Path(sys.argv[1])
    report = {"steps": {}}
    for env_id in ENV_IDS:
        for obs_mode in ("rgb", "state", "measurements"):
            env = gym.make(env_id, obs_mode=obs_mode)
            obs, _ = env.reset(seed=0)
            for _ in range(2):
                obs, reward, *_ = env.step(env.action_space.sample())
            report["steps"][f"{env_id} {obs_mode}"] = bool(
                env.observation_space.contains(obs) and np.isfinite(reward)
            )
            env.close()


    def command(*argv):
        stdout, stderr = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
            code = main(list(argv))
        return {"code": code, "out": stdout.getvalue(), "err": stderr.getvalue()}


    report["list"] = command("list")
    report["compare"] = command(
        "compare", "--env", "BallTable-v0", "--observers", "kf-measurements,oracle",
        "--controllers", "lqr", "--episodes", "1", "--steps", "25",
        "--out", str(out / "compare"), "--no-progress",
    )
    report["compare_files"] = sorted(p.name for p in (out / "compare").iterdir())
    report["demo"] = command(
        "demo", "--seconds", "1", "--frame-every", "25", "--out", str(out / "demo")
    )
    report["demo_frames"] = len(list((out / "demo" / "frames").glob("frame_*.png")))
    zip_path = out / "model.zip"
    zip_path.write_bytes(b"")
    refused = {
        "train": ("train", "--env", "BallTable-v0", "--algo", "ppo", "--obs", "state",
                  "--timesteps", "64", "--out", str(out / "train")),
        "evaluate": ("evaluate", "--model", f"ppo:{out / 'train'}"),
        "learned": ("compare", "--env", "BallCatcher-v1", "--observers",
                    "kf-measurements,learned-measurements", "--controllers", "intercept",
                    "--episodes", "1", "--out", str(out / "learned"), "--no-progress"),
        "learned_kf_run": ("run", "--env", "TargetFollower-v0", "--observer", "learned-kf",
                           "--controller", "vtc", "--episodes", "1",
                           "--out", str(out / "learned_kf_run"), "--no-progress"),
        "agent": ("compare", "--env", "BallTable-v0", "--observers", "kf-measurements",
                  "--controllers", "lqr,ppo:ball_table-estimate", "--episodes", "1",
                  "--out", str(out / "agent"), "--no-progress"),
        "policy_zip": ("run", "--env", "BallTable-v0", "--observer", "kf-measurements",
                       "--controller", f"ppo:{zip_path}", "--episodes", "1",
                       "--out", str(out / "policy_zip"), "--no-progress"),
        "benchmark": ("benchmark", "--env", "BallTable-v0", "--observer",
                      "learned-measurements", "--controller", "lqr", "--episodes", "1",
                      "--out", str(out / "benchmark"), "--no-progress"),
    }
    report["refused"] = {name: command(*argv) for name, argv in refused.items()}
    report["refused_wrote"] = {name: (out / name).exists() for name in refused}

    api = {}
    env = gym.make("observer_gym/BallTable-v0", obs_mode="measurements")
    for name, call in {
        "VisionObserver": lambda: VisionObserver(env, observer="learned-kf"),
        "compare": lambda: observer_gym.compare(
            env="BallTable-v0", observers=["learned-measurements"], controllers=["lqr"],
            episodes=1, out_dir=out / "api",
        ),
        "agent": lambda: observer_gym.run(
            env="BallTable-v0", observer="kf-measurements",
            controller="ppo:ball_table-estimate", episodes=1, out_dir=out / "api",
        ),
    }.items():
        try:
            call()
            api[name] = None
        except ExtraNotInstalled as exc:
            api[name] = [isinstance(exc, ImportError), str(exc)]
    env.close()
    try:
        import observer_gym.train.rl.training  # noqa: F401  (stable-baselines3 at import)

        api["import training"] = None
    except ExtraNotInstalled as exc:
        api["import training"] = [isinstance(exc, ImportError), str(exc)]
    report["api"] = api
    report["attempts"] = ATTEMPTS
    report["loaded"] = sorted(m for m in sys.modules if m.split(".")[0] in BLOCKED)
    print(json.dumps(report))
    """
)


@pytest.fixture(scope="module")
def light(tmp_path_factory) -> dict:
    """What one interpreter without the [rl] modules saw (the module docstring)."""
    out = tmp_path_factory.mktemp("light")
    result = subprocess.run(
        [sys.executable, "-c", CHILD, str(out)], capture_output=True, text=True, timeout=300
    )
    assert result.returncode == 0, result.stderr[-3000:]
    return json.loads(result.stdout.splitlines()[-1])


def test_nothing_tries_to_import_torch_or_stable_baselines3(light):
    assert light["attempts"] == [] and light["loaded"] == []


def test_every_env_makes_and_steps_in_every_mode(light):
    from observer_gym.envs import ENV_IDS

    assert set(light["steps"]) == {
        f"{env_id} {mode}" for env_id in ENV_IDS for mode in ("rgb", "state", "measurements")
    }
    assert all(light["steps"].values()), light["steps"]


def test_classical_compare_and_demo_run(light):
    compare, demo = light["compare"], light["demo"]
    assert compare["code"] == 0, compare["err"]
    assert "kf-measurements" in compare["out"] and "oracle" in compare["out"]
    assert "results.json" in light["compare_files"]
    assert demo["code"] == 0, demo["err"]
    assert light["demo_frames"] == 3  # steps 0, 25 of 50 and the last


def test_list_marks_what_needs_rl(light):
    listed = light["list"]
    assert listed["code"] == 0, listed["err"]
    lines = listed["out"].splitlines()
    marked = {line.split()[0] for line in lines if line.startswith("  ") and "[rl]" in line}
    assert {"learned", "learned-kf-measurements", "ppo:ball_table-estimate"} <= marked
    assert not marked & {"kf", "kf-measurements", "oracle", "lqr", "intercept", "pixels"}
    assert f"[rl]: needs PyTorch and stable-baselines3 (not installed): {RL_INSTALL}" in lines


@pytest.mark.parametrize(
    ("case", "command", "needs"),
    [
        ("train", "train", "this command needs stable-baselines3 and PyTorch"),
        ("evaluate", "evaluate", "this command needs stable-baselines3 and PyTorch"),
        ("learned", "compare", "observer 'learned-measurements' needs PyTorch"),
        ("learned_kf_run", "run", "observer 'learned-kf' needs PyTorch"),
        ("agent", "compare", "agent 'ppo:ball_table-estimate' needs stable-baselines3 and PyTorch"),
        ("policy_zip", "run", "needs stable-baselines3 and PyTorch"),
        ("benchmark", "benchmark", "observer 'learned-measurements' needs PyTorch"),
    ],
)
def test_what_needs_rl_is_one_line_with_the_install_line(light, case, command, needs):
    err = light["refused"][case]["err"]
    assert light["refused"][case]["code"] == 2, err
    assert err.startswith(f"observer-gym {command}: error: ") and needs in err, err
    assert err.endswith(f"not installed: {RL_INSTALL}\n") and err.count("\n") == 1, err
    assert not light["refused_wrote"][case]  # refused before any env or output folder


def test_python_api_raises_an_import_error_naming_the_install_line(light):
    api = light["api"]
    assert api["VisionObserver"] == [
        True,
        f"the learned observer of BallTable-v0 needs PyTorch, which is not installed: {RL_INSTALL}",
    ]
    assert api["compare"] == [
        True,
        f"observer 'learned-measurements' needs PyTorch, which is not installed: {RL_INSTALL}",
    ]
    assert api["import training"] == [
        True,
        "training an agent (observer_gym.train.rl) needs stable-baselines3 and PyTorch, which "
        f"are not installed: {RL_INSTALL}",
    ]
    assert api["agent"] == [
        True,
        "agent 'ppo:ball_table-estimate' needs stable-baselines3 and PyTorch, which are not "
        f"installed: {RL_INSTALL}",
    ]
