"""A Ctrl-C (SIGINT) or ``kill`` (SIGTERM) that lands while a command writes a file: the
write finishes (or its set is dropped whole), then the command stops as usual: one line,
exit code 130, no temp file, the last checkpoint intact.

Each command runs in a subprocess whose writer is paused inside the write by a hook (a
file the test watches says it is paused; another, which the test writes after sending the
signal, lets it go on), so the signal lands inside the write every time.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from observer_gym.train.rl.run_dir import latest_checkpoint

# SIGTERM takes the same path as SIGINT once the command line makes it a KeyboardInterrupt:
# the default run sends SIGTERM inside a cell's write; SIGINT there, both inside the
# results write (4-5 s at load 2) and both inside a checkpoint write (a PPO training, 5 s
# idle) are in the slow step
SIGNALS = [
    pytest.param(signal.SIGINT, id="sigint"),
    pytest.param(signal.SIGTERM, id="sigterm", marks=pytest.mark.slow),
]
SIGTERM_FAST = [
    pytest.param(signal.SIGINT, id="sigint", marks=pytest.mark.slow),
    pytest.param(signal.SIGTERM, id="sigterm"),
]
BOTH_SLOW = [pytest.param(p.values[0], id=p.id, marks=pytest.mark.slow) for p in SIGNALS]

# Pauses the first write whose target matches TARGET between writing the temp and renaming
# it into place (os.replace: every atomic writer's last step), then runs the command.
PAUSE_RENAME = textwrap.dedent(
    """
    import os, sys, time
    from pathlib import Path
    pause, target, argv = Path(sys.argv[1]), sys.argv[2], sys.argv[3:]
    real_replace = os.replace

    def replace(src, dst, **kwargs):
        if Path(dst).match(target) and not (pause / "paused").exists():
            (pause / "paused").touch()
            while not (pause / "go").exists():
                time.sleep(0.01)
        real_replace(src, dst, **kwargs)

    os.replace = replace
    from observer_gym.train.cli import main
    sys.exit(main(argv))
    """
)

# Pauses PyTorch's zip writer inside its second write of the first model's parameters (a
# checkpoint's model_<N>.zip): the reported Ctrl-C landed there, and a KeyboardInterrupt
# then breaks the writer ("unexpected pos"), a traceback and exit code 1.
PAUSE_TORCH_SAVE = textwrap.dedent(
    """
    import os, sys, time
    from pathlib import Path
    import torch
    pause, argv = Path(sys.argv[1]), sys.argv[2:]
    real_save = torch.save

    class Paused:
        def __init__(self, f):
            self.f, self.writes = f, 0

        def write(self, data):
            self.writes += 1
            if self.writes == 2 and not (pause / "paused").exists():
                (pause / "paused").touch()
                while not (pause / "go").exists():
                    time.sleep(0.01)
            return self.f.write(data)

        def __getattr__(self, name):
            return getattr(self.f, name)

    def save(obj, f, *args, **kwargs):
        if not isinstance(f, (str, os.PathLike)) and not (pause / "paused").exists():
            f = Paused(f)
        return real_save(obj, f, *args, **kwargs)

    torch.save = save
    from observer_gym.train.cli import main
    sys.exit(main(argv))
    """
)


def _interrupt_paused(command: list[str], pause: Path, signum: int) -> tuple[int, str]:
    """Run ``command`` until its hook says it is paused inside a write, send ``signum``,
    let the write go on; its exit code and output."""
    pause.mkdir()
    process = subprocess.Popen(
        command,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        start_new_session=True,
        # a shell's background job ignores SIGINT; a terminal's foreground job does not
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        deadline = time.monotonic() + 120
        while not (pause / "paused").exists():
            assert process.poll() is None, process.stdout.read().decode()
            assert time.monotonic() < deadline, "the write was not reached within 120 s"
            time.sleep(0.02)
        os.kill(process.pid, signum)
        time.sleep(0.2)  # the signal is taken while the write is still paused
        (pause / "go").touch()
        output, _ = process.communicate(timeout=120)
    finally:
        process.kill()
    return process.returncode, output.decode()


def _temps(folder: Path) -> list[Path]:
    return [p for p in folder.rglob(".*") if ".tmp" in p.name or p.name.startswith(".observer")]


@pytest.mark.parametrize("signum", BOTH_SLOW)
def test_a_signal_inside_a_checkpoint_write_keeps_it_whole(tmp_path, signum):
    """Paused inside torch.save of the first checkpoint: it is completed and named in
    latest.json, state.json says interrupted at it, and the output is train's two lines."""
    from stable_baselines3 import PPO

    out = tmp_path / "run"
    command = [
        sys.executable, "-c", PAUSE_TORCH_SAVE, str(tmp_path / "pause"), "train",
        "--env", "BallTable-v0", "--algo", "ppo", "--obs", "state", "--timesteps", "100000",
        "--n-envs", "1", "--vec-env", "dummy", "--hyperparam", "n_steps=64",
        "--hyperparam", "batch_size=64", "--hyperparam", "checkpoint_freq=64",
        "--hyperparam", "eval_freq=100000", "--out", str(out), "--no-progress",
    ]  # fmt: skip
    code, output = _interrupt_paused(command, tmp_path / "pause", signum)
    assert code == 130, output
    assert "Traceback" not in output
    assert output.startswith("observer-gym train: interrupted at 64 of 100000 steps"), output
    saved = latest_checkpoint(out / "checkpoints")
    assert saved["timesteps"] == 64
    assert PPO.load(saved["model"]).num_timesteps == 64
    state = json.loads((out / "state.json").read_text())
    assert (state["status"], state["last_checkpoint_timesteps"]) == ("interrupted", 64)
    assert not _temps(out)


SWEEP = [
    "sweep", "--vary", "measurement_noise_px=0,2", "--observers", "oracle",
    "--controllers", "lqr", "--episodes", "1", "--steps", "5", "--no-progress",
]  # fmt: skip


@pytest.mark.parametrize("signum", SIGTERM_FAST)
def test_a_signal_inside_a_cell_write_keeps_the_cell(tmp_path, signum):
    """Paused before the first cell file's rename: the cell is written whole, nothing
    after it runs, and the command says how to resume in one line."""
    out = tmp_path / "sweep"
    command = [
        sys.executable, "-c", PAUSE_RENAME, str(tmp_path / "pause"), "cells/*.json",
        *SWEEP, "--out", str(out),
    ]  # fmt: skip
    code, output = _interrupt_paused(command, tmp_path / "pause", signum)
    assert code == 130, output
    assert output.splitlines() == [
        f"observer-gym sweep: interrupted; the finished cells are kept in {out}: run the "
        "same command again to resume"
    ]
    cells = list((out / "cells").glob("*.json"))
    assert len(cells) == 1  # the paused one, whole; the second cell never ran
    assert len(json.loads(cells[0].read_text())["episodes"]) == 1
    assert not (out / "results.json").exists()
    assert not _temps(out)


COMPARE = [
    "compare", "--observers", "oracle", "--controllers", "lqr,pid", "--episodes", "1",
    "--steps", "5", "--no-progress",
]  # fmt: skip


@pytest.mark.parametrize("signum", BOTH_SLOW)
def test_a_signal_inside_the_results_write_keeps_the_whole_set(tmp_path, signum):
    """Paused before results.json reaches the output folder, the last of the set: every
    output is in place and whole, then the command stops with one line."""
    out = tmp_path / "compare"
    command = [
        sys.executable, "-c", PAUSE_RENAME, str(tmp_path / "pause"), "compare/results.json",
        *COMPARE, "--out", str(out),
    ]  # fmt: skip
    code, output = _interrupt_paused(command, tmp_path / "pause", signum)
    assert code == 130, output
    assert output.splitlines() == ["observer-gym compare: interrupted"]
    results = json.loads((out / "results.json").read_text())
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()) == sorted(
        results["files"]
    )
    assert not _temps(out)
