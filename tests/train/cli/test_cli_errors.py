"""A user's mistake on the ``observer-gym`` command line is one line on stderr naming
what was wrong and what is allowed, exit code 2, never a traceback; it is found before
any env is built and (but for a hyperparameter's name, which stable-baselines3 knows)
before the heavy imports. The mistakes are made in this process (``main(argv)``); what
needs an interpreter of its own (which modules a mistake or ``--help`` imports, the
command as a process) runs in subprocesses. The command's light copy of the systems' names
(:mod:`observer_gym.train.core.checks`) is the layers', with the library's messages."""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from observer_gym.envs import SYSTEMS
from observer_gym.train.cli import build_parser, main
from observer_gym.train.core import checks
from observer_gym.train.core.systems import controller_choices, observer_choices
from observer_gym.train.experiments.request import check_pair, check_pair_of
from observer_gym.train.rl.agent_env import ESTIMATE_SOURCES, OBS_TYPES, observer_for
from observer_gym.train.rl.hyperparams import ALGOS, TRAINING_DEFAULTS, check_algorithm_keys
from observer_gym.train.rl.normalizer_file import record_final_files
from observer_gym.train.rl.run_dir import write_config

CLI = [sys.executable, "-m", "observer_gym.train.cli"]
# never imported to parse a command line or to find a mistake in it
# What a mistake or --help must not wait for: the multi-second imports. The layers
# (estimation, controllers, tasks: ~1.5 s with SciPy, python-control and matplotlib) are
# read for the systems' names, so a system added to SYSTEMS needs no edit in the command.
HEAVY = ("torch", "stable_baselines3", "ray")


def _fake_run(folder: Path, obs: str = "state", model: bool = True) -> Path:
    """A folder that looks like a PPO run of BallTable-v0 trained on ``obs``."""
    folder.mkdir()
    config = {
        "env_id": "observer_gym/BallTable-v0",
        "algo": "ppo",
        "obs": obs,
        "observer": {"state": "oracle", "rgb": "pixels"}.get(obs, "kf-measurements"),
        "env_kwargs": {},
    }
    write_config(folder, config)
    if model:
        (folder / "model.zip").write_bytes(b"")
        record_final_files(folder)  # as a finished run records it
    return folder


STATE_RUN = "{state_run}"  # replaced by a fake state-trained run's folder
EMPTY_RUN = "{empty_run}"  # a run folder with config.json but no model yet
RUN = ["run", "--no-progress"]
COMPARE = ["compare", "--no-progress"]
TRAIN = ["train", "--no-progress", "--algo", "ppo", "--obs", "state"]
OUT = "{out}"  # replaced by the case's output folder (which must stay unwritten)

CASES = {
    # --- a controller that does not fit the env
    "run-foreign-controller": (
        [*RUN, "--env", "BallCatcher-v1", "--observer", "oracle", "--controller", "lqr"],
        "BallCatcher-v1 takes: intercept, ppo:DIR, sac:DIR, td3:DIR",
    ),
    "run-foreign-controller-workers": (
        [*RUN, "--env", "BallCatcher-v1", "--observer", "kf", "--controller", "lqr", "--workers=2"],
        "BallCatcher-v1 takes: intercept, ppo:DIR, sac:DIR, td3:DIR",
    ),
    "compare-foreign-controller": (
        [*COMPARE, "--env=TargetFollower-v0", "--observers=oracle", "--controllers=vtc,intercept"],
        "TargetFollower-v0 takes: vtc, ppo:DIR, sac:DIR, td3:DIR",
    ),
    # --- a bad env option: an unknown key, a value out of range, obs_mode
    "run-unknown-env-option": (
        [*RUN, "--observer", "oracle", "--controller", "lqr", "--env-option", "hfov=60"],
        "BallTableConfig has no option 'hfov'. Did you mean 'hfov_deg'?",
    ),
    "run-bad-env-option-workers": (
        [*RUN, "--observer=kf", "--controller=lqr", "--workers=2", "--env-option=hfov_deg=500"],
        "hfov_deg=500 is out of range; allowed: [20.0, 120.0]",
    ),
    "run-env-option-obs-mode": (
        [*RUN, "--observer", "oracle", "--controller", "lqr", "--env-option", "obs_mode=rgb"],
        "obs_mode is not allowed: the observer decides it",
    ),
    "run-bad-render-mode": (
        [*RUN, "--observer", "oracle", "--controller", "lqr", "--env-option", "render_mode=x"],
        "render_mode='x' is not supported",
    ),
    "compare-bad-env-option": (
        [
            *COMPARE,
            "--env=BallCatcher-v1",
            "--observers=oracle,kf",
            "--controllers=intercept",
            "--env-option=latency_s=-1",
        ],
        "latency_s=-1 is out of range",
    ),
    "train-unknown-env-option": (
        [*TRAIN, "--env-option", "camera=single"],
        "BallTableConfig has no option 'camera'",
    ),
    "train-env-option-obs-mode": (
        [*TRAIN, "--env-option", "obs_mode=rgb"],
        "obs_mode is not allowed: --obs decides it",
    ),
    # --- train --randomize: the form, the key, the range the env takes at both ends
    "train-randomize-unknown-key": (
        [*TRAIN, "--env=BallCatcher-v1", "--randomize", "latency=0:0.01"],
        "randomize latency: BallCatcher-v1 has no option 'latency'; allowed: ",
    ),
    "train-randomize-low-above-high": (
        [*TRAIN, "--env=BallCatcher-v1", "--randomize", "latency_s=0.02:0.01"],
        "randomize latency_s: LOW=0.02 is above HIGH=0.01; need LOW <= HIGH",
    ),
    "train-randomize-not-numbers": (
        [*TRAIN, "--env=BallCatcher-v1", "--randomize", "latency_s=none:0.01"],
        "latency_s: LOW and HIGH must be numbers, got 'none:0.01'",
    ),
    "train-randomize-no-range": (
        [*TRAIN, "--env=BallCatcher-v1", "--randomize", "latency_s=0.01"],
        "latency_s: expected LOW:HIGH or A|B|...",
    ),
    "train-randomize-high-out-of-range": (
        [*TRAIN, "--env=BallCatcher-v1", "--randomize", "latency_s=0:0.9"],
        "randomize latency_s=0.9: BallCatcher-v1 refuses it: latency_s=0.9 is out of range; "
        "allowed: [0.0, 0.5]",
    ),
    "train-randomize-low-out-of-range": (
        [*TRAIN, "--env=TargetFollower-v0", "--randomize", "calib_focal_error=-0.1:0.05"],
        "randomize calib_focal_error=-0.1: TargetFollower-v0 refuses it: "
        "calib_focal_error=-0.1 is out of range; allowed: [0.0, 0.5]",
    ),
    "train-randomize-bad-choice": (
        [*TRAIN, "--env=BallCatcher-v1", "--randomize", "camera_preset=alternating|offsets"],
        "randomize camera_preset='offsets': BallCatcher-v1 refuses it: "
        "camera_preset='offsets' is not allowed; choose one of",
    ),
    "train-randomize-and-env-option": (
        [
            *TRAIN,
            "--env=BallCatcher-v1",
            "--randomize=latency_s=0:0.01",
            "--env-option=latency_s=0",
        ],
        "--randomize and --env-option both give latency_s",
    ),
    "train-randomize-twice": (
        [
            *TRAIN,
            "--env=BallCatcher-v1",
            "--randomize=latency_s=0:0.01",
            "--randomize=latency_s=0:0.02",
        ],
        "--randomize gives latency_s more than once",
    ),
    "train-resume-with-randomize": (
        ["train", "--no-progress", "--resume", STATE_RUN, "--randomize", "latency_s=0:0.01"],
        "--resume continues a run with its own settings; drop --randomize",
    ),
    # --- an observer the env does not have
    "run-stkf-on-balltable": (
        [*RUN, "--env", "BallTable-v0", "--observer", "stkf", "--controller", "lqr"],
        "unknown observer 'stkf' for observer_gym/BallTable-v0; allowed: oracle, kf, "
        "kf-measurements, kf-latency, kf-latency-measurements, ekf, ekf-measurements, raw, "
        "raw-measurements, oracle-visible, oracle-visible-measurements, learned, "
        "learned-measurements, learned-kf, learned-kf-measurements, pixels",
    ),
    "compare-stkf-on-balltable": (
        [*COMPARE, "--observers", "oracle,stkf", "--controllers", "lqr"],
        "unknown observer 'stkf' for observer_gym/BallTable-v0",
    ),
    "evaluate-stkf-on-balltable": (
        ["evaluate", "--no-progress", "--model", STATE_RUN, "--observer", "stkf"],
        "unknown observer 'stkf' for observer_gym/BallTable-v0",
    ),
    # --- camera frames for a controller of the state layout
    "run-pixels-with-lqr": (
        [*RUN, "--observer", "pixels", "--controller", "lqr"],
        "controller 'lqr' acts on the state layout; observer 'pixels' gives camera frames",
    ),
    "compare-pixels-with-lqr": (
        [*COMPARE, "--observers", "oracle,pixels", "--controllers", "lqr,pid"],
        "observer 'pixels' gives camera frames",
    ),
    "evaluate-pixels-for-a-state-agent": (
        ["evaluate", "--no-progress", "--model", STATE_RUN, "--observer", "pixels"],
        "trained with --obs state: it needs an observer but 'pixels'",
    ),
    # --- a missing model folder, or one without a model
    "evaluate-missing-model": (
        ["evaluate", "--no-progress", "--model", "/nonexistent/run"],
        "/nonexistent/run is not an observer-gym training run (no such folder)",
    ),
    "evaluate-no-model-yet": (
        ["evaluate", "--no-progress", "--model", EMPTY_RUN],
        "has neither model.zip nor a checkpoint yet",
    ),
    "run-missing-agent": (
        [*RUN, "--observer", "oracle", "--controller", "ppo:/nonexistent/run"],
        "/nonexistent/run is not an observer-gym training run",
    ),
    "run-agent-without-model": (
        [*RUN, "--observer", "oracle", "--controller", f"ppo:{EMPTY_RUN}"],
        "has neither model.zip nor a checkpoint yet",
    ),
    "compare-missing-agent": (
        [*COMPARE, "--observers", "oracle", "--controllers", "lqr,sac:/nonexistent/run"],
        "/nonexistent/run is not an observer-gym training run",
    ),
    "train-resume-missing-run": (
        ["train", "--no-progress", "--resume", "/nonexistent/run"],
        "/nonexistent/run is not an observer-gym training run",
    ),
    "train-resume-with-settings": (
        ["train", "--no-progress", "--resume", STATE_RUN, "--obs", "rgb"],
        "--resume continues a run with its own settings; drop --obs",
    ),
    # --- a bad hyperparameter
    "train-unknown-hyperparam": (
        [*TRAIN, "--hyperparam", "learning_rat=1e-4"],
        "unknown hyperparameter(s) ['learning_rat'] for PPO (did you mean 'learning_rate'?)",
    ),
    "train-hyperparam-set-by-train": (
        [*TRAIN, "--hyperparam", "seed=3"],
        "observer-gym train sets them: seed (--seed)",
    ),
    "train-bad-training-key": (
        [*TRAIN, "--hyperparam", "n_envs=0"],
        "hyperparameter n_envs must be an integer >= 1",
    ),
    # --- train --seeds: the list, and the options that go with it
    "train-seeds-empty-item": ([*TRAIN, "--seeds", "0,,1"], "'' in '0,,1' is not a seed"),
    "train-seeds-duplicate": ([*TRAIN, "--seeds", "0,1,0"], "lists seed(s) 0 more than once"),
    "train-seeds-negative": ([*TRAIN, "--seeds=-1"], "seeds must be integers >= 0"),
    "train-seed-and-seeds": (
        [*TRAIN, "--seed", "1", "--seeds", "0,1"],
        "--seed trains one agent, --seeds several: give one of them",
    ),
    "train-workers-without-seeds": (
        [*TRAIN, "--workers", "2"],
        "--workers apply to --seeds (several seeds) only",
    ),
    "train-seeds-address-without-ray": (
        [*TRAIN, "--seeds", "0,1", "--address", "auto"],
        "address 'auto' is a Ray cluster's address: it needs backend 'ray'",
    ),
    "train-resume-with-seeds": (
        ["train", "--no-progress", "--resume", STATE_RUN, "--seeds", "0,1"],
        "--resume continues a run with its own settings; drop --seeds",
    ),
    "run-multi-seed-agent": (
        [*RUN, "--observer", "oracle", "--controller", "ppo:{seeds_run}"],
        "holds a multi-seed run (seeds 0, 1), not one agent",
    ),
    # --- --algo and --obs are required
    "train-without-algo": (
        ["train", "--obs", "state"],
        "the following arguments are required: --algo",
    ),
    "train-without-algo-and-obs": (
        ["train"],
        "the following arguments are required: --algo, --obs",
    ),
    # --- argparse's own checks, one line too
    "run-unknown-env": (
        [*RUN, "--env", "BallJuggler-v0", "--observer", "oracle", "--controller", "lqr"],
        "unknown env 'BallJuggler-v0'",
    ),
    "run-retired-env-id": (
        [*RUN, "--env", "BallCatcher-v0", "--observer", "oracle", "--controller", "intercept"],
        "env 'BallCatcher-v0' is no longer registered: BallCatcher-v1 replaced it",
    ),
    "demo-negative-seconds": (["demo", "--seconds", "-1"], "must be a positive number"),
    "reproduce-no-runs": (
        ["reproduce", "tsai2009", "--runs", "0"],
        "argument --runs: must be an integer >= 1, got 0",
    ),
    "reproduce-short-steps": (
        ["reproduce", "tsai2009", "--steps", "5"],
        "argument --steps: must be an integer >= 10, got 5",
    ),
    "reproduce-negative-seed": (
        ["reproduce", "linderoth2010", "--seed", "-1"],
        "argument --seed: must be an integer >= 0, got -1",
    ),
    "study-unknown-level": (
        ["study", "delay-rl", "--env", "BallTable-v0", "--levels", "none,extreme", "--out", OUT],
        "unknown level 'extreme'; allowed: none, moderate, heavy",
    ),
    "study-unknown-input": (
        ["study", "delay-rl", "--env", "BallTable-v0", "--inputs", "belief", "--out", OUT],
        "unknown input 'belief'; allowed: newest, stack, kf-latency, kf, truth",
    ),
    "study-without-out": (
        ["study", "delay-rl", "--env", "BallCatcher-v1"],
        "--out required (or --check DIR)",
    ),
    "study-check-with-env": (
        ["study", "delay-rl", "--check", "{state_run}", "--env", "BallTable-v0"],
        "--check takes no --env: it checks a finished folder",
    ),
    "study-duplicate-seeds": (
        ["study", "delay-rl", "--env", "BallTable-v0", "--seeds", "0,0", "--out", OUT],
        "argument --seeds",
    ),
    "study-ray-workers": (
        [
            "study",
            "delay-rl",
            "--env",
            "BallTable-v0",
            "--backend",
            "ray",
            "--workers",
            "2",
            "--out",
            OUT,
        ],
        "workers applies to the local backend only",
    ),
}


def _runs(folder: Path) -> dict[str, str]:
    """The fake runs the cases name, in ``folder``."""
    seeds_run = folder / "seeds-run"
    seeds_run.mkdir()
    for seed in (0, 1):
        _fake_run(seeds_run / f"seed_{seed}")
    return {
        "state_run": str(_fake_run(folder / "state-run")),
        "empty_run": str(_fake_run(folder / "empty-run", model=False)),
        "seeds_run": str(seeds_run),
    }


@pytest.fixture
def runs(tmp_path: Path) -> dict[str, str]:
    return _runs(tmp_path)


def _argv(argv: list[str], runs: dict[str, str], out: Path) -> list[str]:
    argv = [word.format(**runs, out=out) for word in argv]
    if argv[0] in ("run", "compare", "train", "evaluate") and "--resume" not in argv:
        argv += ["--out", str(out)]
    return argv


def _main(argv: list[str], capsys) -> tuple[object, str, str]:
    """``observer-gym ARGV`` in this process: (exit code, stdout, stderr)."""
    try:
        code: object = main(argv)
    except SystemExit as exc:  # argparse's mistakes and --help
        code = exc.code
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.mark.parametrize("case", sorted(CASES))
def test_a_mistake_is_one_line_and_exit_code_2(case, runs, tmp_path, capsys):
    argv, message = CASES[case]
    out = tmp_path / "out"
    code, stdout, stderr = _main(_argv(argv, runs, out), capsys)
    assert code == 2, stderr
    lines = stderr.splitlines()
    assert len(lines) == 1, stderr
    command = " ".join(argv[:2] if argv[0] in ("reproduce", "study") else argv[:1])
    assert lines[0].startswith(f"observer-gym {command}: error: "), lines[0]
    assert message in lines[0]
    assert stdout == ""
    assert not out.exists()


def test_a_mistake_through_the_command_is_one_line_without_traceback(runs, tmp_path):
    """The mistakes above, checked in this process, are the command's: one of them through
    ``python -m observer_gym.train.cli`` in a process of its own."""
    argv, message = CASES["train-randomize-high-out-of-range"]
    out = tmp_path / "out"
    result = subprocess.run(
        [*CLI, *_argv(argv, runs, out)], capture_output=True, text=True, timeout=120
    )
    assert "Traceback" not in result.stderr, result.stderr
    assert result.returncode == 2, result.stderr
    assert result.stderr == f"observer-gym train: error: {message}\n"
    assert result.stdout == ""
    assert not out.exists()


@pytest.mark.parametrize("algo", ALGOS)
def test_the_hyperparameter_error_lists_only_public_settable_names(algo):
    with pytest.raises(ValueError, match="unknown hyperparameter") as error:
        check_algorithm_keys({**TRAINING_DEFAULTS, "foo": 1}, algo)
    assert "\n" not in str(error.value)
    allowed = str(error.value).split("allowed: training keys ", 1)[1]
    names = [name.strip() for name in re.split(r",| and \w+'s ", allowed)]
    assert "learning_rate" in names and "policy_kwargs" in names and "policy" in names
    assert not [name for name in names if name.startswith("_")], names
    for set_by_train in ("self", "env", "seed", "device", "verbose"):
        assert set_by_train not in names


FOUND_BEFORE_HEAVY = [
    "run-foreign-controller",
    "run-stkf-on-balltable",
    "run-pixels-with-lqr",
    "run-missing-agent",
    "evaluate-missing-model",
    "train-without-algo-and-obs",
    "train-seeds-duplicate",
    "run-multi-seed-agent",
    "run-unknown-env-option",
    "compare-bad-env-option",
    "train-unknown-env-option",
    "train-randomize-unknown-key",
    "train-randomize-high-out-of-range",
    "train-randomize-and-env-option",
]
HELP = [
    *(
        [command]
        for command in (
            "demo",
            "run",
            "compare",
            "sweep",
            "train",
            "evaluate",
            "benchmark",
            "record",
            "reproduce",
            "study",
        )
    ),
    [],
    ["reproduce", "linderoth2010"],
    ["reproduce", "tsai2009"],
    ["study", "delay-rl"],
]


@pytest.fixture(scope="module")
def fresh_command(tmp_path_factory) -> dict[str, tuple[int, list[str]]]:
    """{case or help argv: (exit code, heavy modules imported)} of the command run with the
    argv in an interpreter that had imported only the command (tests/train/fresh_imports.py:
    one subprocess, a forked child per argv)."""
    folder = tmp_path_factory.mktemp("fresh-command")
    runs = _runs(folder)
    argvs = {case: _argv(CASES[case][0], runs, folder / "out") for case in FOUND_BEFORE_HEAVY}
    argvs |= {" ".join([*argv, "--help"]): [*argv, "--help"] for argv in HELP}
    script = Path(__file__).parents[1] / "fresh_imports.py"
    result = subprocess.run(
        [sys.executable, str(script), "cli", json.dumps(HEAVY)]
        + [json.dumps(argv) for argv in argvs.values()],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr
    return {
        key: tuple(answer) for key, answer in zip(argvs, json.loads(result.stdout), strict=True)
    }


@pytest.mark.slow  # fresh_command: a forked child per argv (6.6 s idle)
@pytest.mark.parametrize("case", FOUND_BEFORE_HEAVY)
def test_mistakes_are_found_before_the_heavy_imports(case, fresh_command):
    assert fresh_command[case] == (2, [])


@pytest.mark.slow  # fresh_command: a forked child per argv (6.6 s idle)
@pytest.mark.parametrize("argv", HELP)
def test_help_imports_no_heavy_module(argv, fresh_command):
    assert fresh_command[" ".join([*argv, "--help"])] == (0, [])


def _subparser(parser: argparse.ArgumentParser, command: str) -> argparse.ArgumentParser:
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return sub.choices[command]


def test_train_usage_shows_algo_and_obs_as_required():
    usage = " ".join(_subparser(build_parser(), "train").format_usage().split())
    assert "--algo {ppo,sac,td3} --obs {state,estimate,rgb,measurements}" in usage
    assert "[--algo" not in usage and "[--obs {" not in usage
    assert "[--resume DIR]" in usage


def test_resume_needs_neither_algo_nor_obs():
    args = build_parser().parse_args(["train", "--resume", "runs/x", "--timesteps", "10"])
    assert (args.algo, args.obs, args.resume, args.timesteps) == (None, None, Path("runs/x"), 10)


# --- the command's checks and the library's agree ------------------------------------
def test_the_checks_feed_an_agent_from_the_observer_train_uses():
    for system in SYSTEMS:
        for obs in OBS_TYPES:
            for source in ESTIMATE_SOURCES:
                assert checks.agent_observer(system.env_id, obs, source) == observer_for(
                    system.env_id, obs, source
                )
        for observer in (*checks.names_for(system.env_id).observer_modes, "nope"):
            assert _message(checks.agent_observer, system.env_id, "estimate", "rgb", observer) == (
                _message(observer_for, system.env_id, "estimate", "rgb", observer)
            )


def _message(check, *args) -> str | None:
    try:
        check(*args)
    except ValueError as exc:
        return str(exc)
    return None


def test_the_checks_say_what_the_library_says(tmp_path):
    runs = {
        "ppo:" + str(_fake_run(tmp_path / "state", "state")),
        "ppo:" + str(_fake_run(tmp_path / "rgb", "rgb")),
        "ppo:" + str(_fake_run(tmp_path / "empty", model=False)),
        "sac:" + str(tmp_path / "state"),  # a PPO run named as SAC
        "td3:" + str(tmp_path / "none"),
    }
    names = {*controller_choices(), "lqg", *runs}
    for system in SYSTEMS:
        for observer in [*observer_choices(), "no-such-observer"]:
            for controller in sorted(names):
                cli_side = _message(checks.check_observer, system.short_id, observer) or _message(
                    check_pair_of, system, observer, controller
                )
                library = _message(check_pair, system.short_id, observer, controller)
                assert cli_side == library, (system.short_id, observer, controller)
