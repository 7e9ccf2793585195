"""An ``observer-gym`` command that pauses at a chosen point, for the tests of two
commands racing into one folder: ``python paused_command.py POINT READY GO ARGS...``
runs ``observer-gym ARGS...`` and, when it reaches POINT, creates the file READY and
waits until the file GO exists (at most :data:`WAIT_S`), then carries on.

Points, each the last moment before the command writes what a second command's check
would see, in today's code and in the locked code alike:

- ``train-config``: a new training run about to write its config.json;
- ``train-learn``: a resumed run, checked, about to build its envs and train;
- ``sweep-arguments``: a new sweep, checked, about to write its sweep.json.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

WAIT_S = 120.0


def pause(ready: Path, go: Path) -> None:
    ready.touch()
    deadline = time.monotonic() + WAIT_S
    while not go.exists() and time.monotonic() < deadline:
        time.sleep(0.02)


def paused(function: Any, ready: Path, go: Path) -> Any:
    """``function``, pausing (:func:`pause`) before its first call runs."""
    calls = []

    def wrapper(*args: Any, **kwargs: Any) -> Any:
        if not calls:
            pause(ready, go)
        calls.append(1)
        return function(*args, **kwargs)

    return wrapper


def main() -> int:
    point, ready, go, *argv = sys.argv[1:]
    ready, go = Path(ready), Path(go)
    if point in ("train-config", "train-learn"):
        from observer_gym.train.rl import training

        name = {"train-config": "write_config", "train-learn": "learn"}[point]
        setattr(training, name, paused(getattr(training, name), ready, go))
    elif point == "sweep-arguments":
        from observer_gym.train.experiments import sweep

        sweep.write_json_atomic = paused(sweep.write_json_atomic, ready, go)
    else:
        raise SystemExit(f"unknown point {point!r}")
    from observer_gym.train.cli import main as observer_gym

    return observer_gym(argv)


if __name__ == "__main__":
    sys.exit(main())
