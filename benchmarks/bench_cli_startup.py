"""Start-up time of the ``observer-gym`` command: ``observer-gym --help`` and each
subcommand's ``--help`` (each study's for ``reproduce``), timed as whole processes,
wall clock from start to exit. Each command runs ``--repeats`` times, the commands
taking turns so that drift hits them alike; the table gives the median and the slowest
run, with the target (well under a second, 0.5 s here) for the median.

    python benchmarks/bench_cli_startup.py [--repeats 5] [--command observer-gym]

``--command`` is how to start the CLI (default: the ``observer-gym`` next to this
Python, else ``python -m observer_gym.train.cli``).
"""

from __future__ import annotations

import argparse
import shlex
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

TARGET_S = 0.5
HELP_COMMANDS = (
    [],
    ["demo"],
    ["run"],
    ["compare"],
    ["sweep"],
    ["train"],
    ["evaluate"],
    ["reproduce"],
    ["reproduce", "linderoth2010"],
    ["reproduce", "tsai2009"],
)


def default_command() -> list[str]:
    """The ``observer-gym`` script beside this interpreter, else ``python -m``."""
    script = Path(sys.executable).with_name("observer-gym")
    if script.exists():
        return [str(script)]
    found = shutil.which("observer-gym")
    return [found] if found else [sys.executable, "-m", "observer_gym.train.cli"]


def time_once(argv: list[str]) -> float:
    """Wall-clock seconds of one run of ``argv``; it must exit 0."""
    tic = time.perf_counter()
    result = subprocess.run(argv, capture_output=True, text=True)
    elapsed = time.perf_counter() - tic
    if result.returncode != 0:
        raise SystemExit(f"{shlex.join(argv)} exited {result.returncode}: {result.stderr}")
    return elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=5, help="runs per command (default: 5)")
    parser.add_argument(
        "--command", default=None, help="how to start the CLI (default: observer-gym)"
    )
    args = parser.parse_args()
    command = shlex.split(args.command) if args.command else default_command()

    times: dict[str, list[float]] = {}
    for _ in range(args.repeats):
        for words in HELP_COMMANDS:
            label = shlex.join(["observer-gym", *words, "--help"])
            times.setdefault(label, []).append(time_once([*command, *words, "--help"]))

    width = max(len(label) for label in times)
    print(
        f"CLI start-up, {args.repeats} runs each ({shlex.join(command)}); target median < "
        f"{TARGET_S:.1f} s"
    )
    print(f"| {'command':<{width}} | median (s) | max (s) | target |")
    print(f"|{'-' * (width + 2)}|-----------:|--------:|:------:|")
    for label, runs in times.items():
        median = statistics.median(runs)
        verdict = "ok" if median < TARGET_S else "SLOW"
        print(f"| {label:<{width}} | {median:10.2f} | {max(runs):7.2f} | {verdict:^6} |")


if __name__ == "__main__":
    main()
