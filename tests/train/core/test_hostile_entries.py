"""Outside entries that misbehave (issue 43): they cannot change what an episode records,
and every way they fail is one line naming the entry, the episode's seed and its step."""

from __future__ import annotations

import importlib
import json
import sys
import threading

import numpy as np
import pytest
from hostile_package import forget_hostile, write_hostile

import observer_gym
from observer_gym.train.cli import main

ENV = "BallTable-v0"
STEPS = 12
COMMON = ["--env", ENV, "--episodes", "1", "--seed", "3", "--steps", str(STEPS), "--no-progress"]


@pytest.fixture
def hostile(tmp_path, monkeypatch):
    """The module ``hostile`` on sys.path (this process and the workers it spawns)."""
    root = write_hostile(tmp_path / "site")
    monkeypatch.syspath_prepend(str(root))
    forget_hostile()
    yield root
    forget_hostile()


def _run(observer, controller, out, **kwargs):
    return observer_gym.run(ENV, observer, controller, episodes=1, seed=3, steps=STEPS,
                            out_dir=out, **kwargs)  # fmt: skip


# --- 4: the ground truth no entry can reach ----------------------------------------------------
def test_an_observer_writing_into_the_ground_truth_is_refused_in_one_line(hostile, tmp_path):
    with pytest.raises(ValueError, match=r"observer 'hostile:forger-measurements'.*read-only") as e:
        _run("hostile:forger-measurements", "lqr", tmp_path / "forged")
    assert "tried before any episode" in str(e.value) and "\n" not in str(e.value)
    assert not (tmp_path / "forged").exists()


def test_an_observer_that_unlocks_its_view_changes_only_its_copy(hostile, tmp_path):
    honest = _run("kf-measurements", "lqr", tmp_path / "kf")
    forged = _run("hostile:unlocking_forger-measurements", "lqr", tmp_path / "forged")
    assert honest.summary["position_rmse_m"] > 0.0
    assert forged.summary["position_rmse_m"] == honest.summary["position_rmse_m"]
    assert forged.summary == honest.summary


@pytest.mark.parametrize("mode", ["forge", "forge_estimate"])
def test_a_controller_writing_into_observe_info_is_refused(hostile, tmp_path, mode):
    with pytest.raises(ValueError, match=r"controller 'hostile:controller'.*observe_info"):
        _run("kf-measurements", "hostile:controller", tmp_path / mode,
             controller_options={"mode": mode})  # fmt: skip
    assert not (tmp_path / mode).exists()


# --- 10: a covariance the NEES cannot use --------------------------------------------------------
@pytest.mark.parametrize(
    ("kind", "what"),
    [
        ("negative", "variance"),
        ("zero", "variance"),
        ("asymmetric", "not symmetric"),
        ("indefinite", "not positive definite"),
    ],
)
def test_a_covariance_the_nees_cannot_use_is_refused(hostile, tmp_path, kind, what):
    with pytest.raises(ValueError, match=what) as e:
        _run("hostile:covariance-measurements", "lqr", tmp_path / kind,
             observer_options={"kind": kind})  # fmt: skip
    message = str(e.value)
    assert "observer 'hostile:covariance-measurements'" in message
    assert "episode seed 3, after 2 steps" in message  # observe #4 follows step 3's action
    assert not (tmp_path / kind).exists()


# --- 17 and 11: an exception, or sys.exit, part-way ----------------------------------------------
@pytest.mark.parametrize(  # two workers: processes of their own, 1.5-3 s each (load ~2): slow
    "workers", ["1", pytest.param("2", marks=pytest.mark.slow)]
)
@pytest.mark.parametrize(
    ("observer", "controller", "said"),
    [
        ("hostile:raises_late-measurements", "lqr", "RuntimeError: the filter diverged"),
        ("kf-measurements", "hostile:controller", "KeyError"),
        ("hostile:exits_in_observe-measurements", "lqr", "SystemExit"),
        ("hostile:exits_in_factory-measurements", "lqr", "SystemExit"),
        ("hostile_exit:make-measurements", "lqr", "SystemExit"),
    ],
)
def test_a_fault_part_way_is_one_line_and_exits_non_zero(
    hostile, tmp_path, capsys, observer, controller, said, workers
):
    out = tmp_path / "out"
    options = ["--controller-option", "mode=raise"] if controller.startswith("hostile") else []
    argv = ["run", "--observer", observer, "--controller", controller, *options, *COMMON,
            "--workers", workers, "--out", str(out)]  # fmt: skip
    code = main(argv)
    err = capsys.readouterr().err
    assert code != 0
    assert err.count("\n") == 1, err
    assert said in err
    assert repr(observer if "hostile" in observer else controller) in err
    assert not (out / "results.json").exists()


def test_sys_exit_in_predict_is_one_line(hostile, tmp_path, capsys):
    argv = ["run", "--observer", "kf-measurements", "--controller", "hostile:controller",
            "--controller-option", "mode=exit", *COMMON,
            "--out", str(tmp_path / "out")]  # fmt: skip
    assert main(argv) != 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "SystemExit" in err and "hostile:controller" in err


# --- 23: an absurd action, options that cannot be recorded ---------------------------------------
def test_a_huge_finite_action_is_clipped_as_the_env_clips_it(hostile, tmp_path):
    import gymnasium as gym

    bound = float(np.max(gym.make(f"observer_gym/{ENV}").action_space.high))
    result = _run("oracle", "hostile:controller", tmp_path / "huge",
                  controller_options={"scale": 1e300})  # fmt: skip
    assert (tmp_path / "huge" / "results.json").is_file()
    effort = result.summary["effort_rms_rad"]
    # saturated at the bound it is applied as, on both tilt axes: sqrt(2) * bound
    assert effort == pytest.approx(np.sqrt(2) * bound, rel=1e-6)


@pytest.mark.parametrize(
    ("options", "named"),
    [({"scale": float("inf")}, "scale"), ({"scale": {1, 2}}, "scale"),
     ({"scale": float("nan")}, "scale")],
)  # fmt: skip
def test_options_that_cannot_be_recorded_are_refused_up_front(hostile, tmp_path, options, named):
    with pytest.raises(ValueError, match=f"controller option {named!r}"):
        _run("oracle", "hostile:controller", tmp_path / "bad", controller_options=options)
    assert not (tmp_path / "bad").exists()


# --- 6 and 7: closures of the same qualname ------------------------------------------------------
def _scaled(scale, built=None, barrier=None):
    def factory(env):
        from observer_gym.controllers import make_controller

        if built is not None:
            built.append((threading.current_thread().name, scale))
        if barrier is not None:
            barrier.wait(timeout=20)
        lqr = make_controller("lqr", env)

        class Scaled:
            def predict(self, obs, state=None, episode_start=None, deterministic=True):
                return scale * np.asarray(lqr.predict(obs)[0]), state

        return Scaled()

    return factory


def test_two_threads_with_same_qualname_closures_run_their_own(tmp_path):
    built: list = []
    barrier = threading.Barrier(2)
    results = {}

    def go(name, scale):
        factory = _scaled(scale, built, barrier)
        results[name] = _run("oracle", factory, tmp_path / name)

    threads = [
        threading.Thread(target=go, args=(n, s), name=n) for n, s in (("a", 1.0), ("b", 0.25))
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(60)
    assert {(name, scale) for name, scale in built} == {("a", 1.0), ("b", 0.25)}
    assert results["a"].summary != results["b"].summary
    assert (
        results["a"].results["config"]["controller"] != results["b"].results["config"]["controller"]
    )


def test_a_resumed_sweep_does_not_reuse_another_closures_cells(tmp_path):
    out = tmp_path / "sweep"

    def sweep(scale):
        return observer_gym.sweep(ENV, {"latency_s": [0.0]}, "oracle", _scaled(scale),
                                  out_dir=out, seeds=[0], steps=STEPS)  # fmt: skip

    first = sweep(1.0)
    with pytest.raises(ValueError, match="holds a sweep with other arguments"):
        sweep(0.25)  # another closure of the same qualname: not the first one's cells
    again = sweep(1.0)  # a closure of the same code and captures: the same entry, resumed
    assert again.results["cells"] == first.results["cells"]


def test_an_objects_identity_is_its_content_in_every_process():
    import subprocess
    from pathlib import Path

    from observer_gym.train.core import entries

    here = entries.object_identity(_scaled(1.0))
    assert here == entries.object_identity(_scaled(1.0))
    assert here != entries.object_identity(_scaled(0.25))
    code = (
        "import sys; sys.path[:0] = sys.argv[1:]; from test_hostile_entries import _scaled;"
        "from observer_gym.train.core import entries;"
        "print(entries.object_identity(_scaled(1.0)))"
    )
    here_and_helpers = [str(Path(__file__).parent), str(Path(__file__).parents[1])]
    there = subprocess.run([sys.executable, "-c", code, *here_and_helpers], capture_output=True,
                           text=True, check=True).stdout.strip()  # fmt: skip
    assert there == here


# --- 19 and the names shown: installed entry points named badly ---------------------------------
@pytest.fixture
def badly_named(tmp_path, monkeypatch):
    """A distribution ``badnames`` whose entry points are named ``kf2-measurements``, with
    an escape code, and ``fine``."""
    from observer_gym.train.core import entries

    root = write_hostile(tmp_path / "site")
    info = root / "badnames-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: badnames\nVersion: 1.0\n")
    (info / "top_level.txt").write_text("hostile\n")
    (info / "entry_points.txt").write_text(
        "[observer_gym.observers]\n"
        "kf2-measurements = hostile:forger\n"
        "red\x1b[31mname = hostile:forger\n"
        "fine = hostile:unlocking_forger\n"
    )
    monkeypatch.syspath_prepend(str(root))
    forget_hostile()
    entries.refresh()
    yield root
    forget_hostile()
    monkeypatch.undo()
    entries.refresh()


def test_an_entry_point_named_measurements_is_refused_by_name_and_list_works(badly_named, capsys):
    assert main(["list"]) == 0
    out, err = capsys.readouterr()
    assert "fine" in out
    assert "kf2-measurements" not in out
    assert "entry point 'kf2-measurements' of badnames is ignored" in err
    assert "may not end in '-measurements'" in err
    assert "\x1b" not in out + err  # the escape code is shown escaped, never raw
    assert "red\\x1b[31mname" in err


def test_an_objects_unprintable_qualname_is_escaped_in_its_name(tmp_path):
    factory = _scaled(1.0)
    factory.__qualname__ = "evil\x1b[2J"
    result = _run("oracle", factory, tmp_path / "escaped")
    name = result.results["config"]["controller"]
    assert "\x1b" not in name and "evil\\x1b[2J@" in name


# --- 8: an entry point's package upgraded --------------------------------------------------------
def _install_upg(root, version: str, body: str) -> None:
    """The distribution ``upg`` at ``version``: controller entry points ``upg-lqr`` (BallTable)
    and ``upg-catch`` (BallCatcher), their module ending in ``body``."""
    from observer_gym.train.core import entries

    package = root / "upg"
    package.mkdir(parents=True, exist_ok=True)
    (package / "__init__.py").write_text("")
    (package / "control.py").write_text(
        "from observer_gym.controllers import make_controller\n\n"
        f"SCALE = {body}\n\n"
        "class Scaled:\n"
        "    def __init__(self, env):\n"
        "        self.lqr = make_controller('lqr', env)\n\n"
        "    def predict(self, obs, state=None, episode_start=None, deterministic=True):\n"
        "        return SCALE * self.lqr.predict(obs)[0], state\n\n"
        "def make_lqr(env):\n    return Scaled(env)\n\n"
        "def make_catch(env):\n    return make_controller('intercept', env)\n"
    )
    for old in root.glob("upg-*.dist-info"):
        for item in old.iterdir():
            item.unlink()
        old.rmdir()
    info = root / f"upg-{version}.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: upg\nVersion: {version}\n")
    (info / "top_level.txt").write_text("upg\n")
    (info / "entry_points.txt").write_text(
        "[observer_gym.controllers]\nupg-lqr = upg.control:make_lqr\n"
        "upg-catch = upg.control:make_catch\n"
    )
    for name in ("upg", "upg.control"):
        sys.modules.pop(name, None)
    importlib.invalidate_caches()
    entries.refresh()


@pytest.fixture
def upg(tmp_path, monkeypatch):
    from observer_gym.train.core import entries

    root = tmp_path / "site"
    root.mkdir()
    monkeypatch.syspath_prepend(str(root))
    yield root
    for name in ("upg", "upg.control"):
        sys.modules.pop(name, None)
    monkeypatch.undo()
    entries.refresh()


def test_an_upgraded_entry_point_does_not_reuse_a_sweeps_cells(upg, tmp_path):
    out = tmp_path / "sweep"
    argv = ["sweep", "--env", ENV, "--vary", "latency_s=0", "--observers", "oracle",
            "--controllers", "upg-lqr", "--episodes", "1", "--steps", str(STEPS),
            "--out", str(out), "--no-progress"]  # fmt: skip
    _install_upg(upg, "1.0", "1.0")
    assert main(argv) == 0
    recorded = json.loads((out / "sweep.json").read_text())
    identity = json.dumps(recorded)
    assert '"version": "1.0"' in identity and "code_sha256" in identity
    _install_upg(upg, "2.0", "0.25")
    assert main(argv) != 0  # not the first sweep's cells: refused as another sweep


def test_an_upgraded_entry_point_does_not_reuse_benchmark_levels(upg, tmp_path, capsys):
    from observer_gym.train.experiments.benchmark.check import check_folder

    out = tmp_path / "bench"
    argv = ["benchmark", "--env", "BallCatcher-v1", "--observer", "kf-measurements",
            "--controller", "upg-catch", "--episodes", "1", "--no-progress",
            "--out", str(out)]  # fmt: skip
    _install_upg(upg, "1.0", "1.0")
    assert main(argv) == 0
    scores = json.loads((out / "scores.json").read_text())
    entry = scores["entries"]["controller"]
    assert entry["package"] == "upg" and entry["version"] == "1.0"
    assert entry["import_path"] == "upg.control:make_catch" and len(entry["code_sha256"]) == 16
    assert "OK" in check_folder(out)
    _install_upg(upg, "2.0", "0.5")
    capsys.readouterr()
    assert main(argv) != 0
    assert "holds another benchmark run" in capsys.readouterr().err


# --- minor: gym.make's own keywords ---------------------------------------------------------------
@pytest.mark.parametrize("steps", [1.5, 0, True, "10"])
def test_max_episode_steps_not_an_integer_is_refused_naming_it(tmp_path, capsys, steps):
    with pytest.raises(ValueError, match=r"max_episode_steps must be an integer >= 1"):
        _run("oracle", "lqr", tmp_path / "api", env_options={"max_episode_steps": steps})
    assert not (tmp_path / "api").exists()
    if isinstance(steps, float):
        option = ["--env-option", f"max_episode_steps={steps}"]
        argv = ["run", "--observer", "oracle", "--controller", "lqr", *COMMON, *option,
                "--out", str(tmp_path / "cli")]  # fmt: skip
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "max_episode_steps must be an integer >= 1" in err


# --- 5: an agent trained on another task --------------------------------------------------------
def _agent_with(tmp_path, options):
    """A copy of the shipped ``ball_catcher-estimate`` agent whose config says it was
    trained with ``options`` too (the config's hash recomputed, as training writes it)."""
    import shutil
    from pathlib import Path

    from observer_gym.train.rl import run_dir

    shipped = Path(run_dir.__file__).parent / "agents" / "ball_catcher-estimate"
    copy = tmp_path / "agent"
    shutil.copytree(shipped, copy)
    config = json.loads((copy / "config.json").read_text())
    config.pop(run_dir.CONFIG_SHA256, None)
    config["env_kwargs"] = {**config["env_kwargs"], **options}
    run_dir.write_config(copy, config)
    return f"ppo:{copy}"


def test_an_agent_trained_on_another_task_is_refused_by_the_benchmark(tmp_path, capsys):
    from observer_gym.train.experiments.benchmark.run import check_benchmark

    agent = _agent_with(tmp_path, {"hole_diameter_m": 0.15, "launch_spread_m": 0.0})
    changed = "change the task: hole_diameter_m=0.15, launch_spread_m=0.0"
    with pytest.raises(ValueError, match=changed):
        check_benchmark("BallCatcher-v1", "kf-measurements", agent, episodes=1)
    out = tmp_path / "bench"
    argv = ["benchmark", "--env", "BallCatcher-v1", "--observer", "kf-measurements",
            "--controller", agent, "--episodes", "1", "--no-progress",
            "--out", str(out)]  # fmt: skip
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "change the task" in err
    assert not (out / "scores.json").exists()


def test_an_agents_view_and_reward_options_still_travel(tmp_path):
    from observer_gym.train.experiments.benchmark.run import check_benchmark

    agent = _agent_with(tmp_path, {"shaping_weight": 2.0})
    request = check_benchmark("BallCatcher-v1", "kf-measurements", agent, episodes=1)
    assert request.agent_env_options == {"shaping_weight": 2.0}
    shipped = check_benchmark("TargetFollower-v0", "pixels", "ppo:target_follower-rgb", episodes=1)
    assert shipped.agent_env_options["desired_width_px"] == pytest.approx(9.1875)
