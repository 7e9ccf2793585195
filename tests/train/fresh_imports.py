"""Jobs that need an interpreter which has imported none of observer-gym, run in one
subprocess: each job in its own child forked from this process, which imports nothing of
the package, so the jobs share one interpreter start-up and none sees what another
imported (tests/train/test_imports.py, tests/train/cli/test_cli_errors.py).

``python fresh_imports.py modules MODULE...``
    every MODULE imported alone; the third-party modules they load are imported once in
    this process first (a fresh interpreter would load them anyway; none of them imports
    observer-gym, which is checked). Prints ``{module: traceback or null}`` as JSON.
``python fresh_imports.py cli HEAVY_JSON ARGV_JSON...``
    ``observer_gym.train.cli.main(argv)`` for every ARGV, each in a fresh child of a
    process that imported only the command; prints ``[[exit code, [heavy modules the
    command imported]], ...]`` as JSON, the heavy modules being those named in HEAVY or
    under them. The command's stdout and stderr are dropped.
"""

from __future__ import annotations

import importlib
import json
import multiprocessing
import os
import sys
import traceback

PACKAGE = "observer_gym"


def _ours(name: str) -> bool:
    return name == PACKAGE or name.startswith(f"{PACKAGE}.")


def _import(module: str) -> str | None:
    try:
        importlib.import_module(module)
    except BaseException:
        return traceback.format_exc()
    return None


def _import_all(modules: list[str]) -> list[str]:
    """Imports every module; the modules they loaded that are not observer-gym's."""
    before = set(sys.modules)
    for module in modules:
        _import(module)
    return [name for name in sys.modules if name not in before and not _ours(name)]


def _run_command(argv: list[str], heavy: list[str]) -> tuple[object, list[str]]:
    from observer_gym.train.cli import main

    with open(os.devnull, "w") as devnull:
        sys.stdout = sys.stderr = devnull
        try:
            code: object = main(argv)
        except SystemExit as exc:
            code = exc.code
        finally:
            sys.stdout, sys.stderr = sys.__stdout__, sys.__stderr__
    return code, _heavy_loaded(heavy)


def _heavy_loaded(heavy: list[str]) -> list[str]:
    return sorted(
        name for name in sys.modules if any(name == h or name.startswith(f"{h}.") for h in heavy)
    )


def _forked(jobs: list[tuple]) -> list:
    """``function(*args)`` of every job, each in a new child forked from this process."""
    # one task per child: each child is forked afresh from this process's state
    with multiprocessing.get_context("fork").Pool(1, maxtasksperchild=1) as pool:
        return [pool.apply(function, args) for function, *args in jobs]


def main(argv: list[str]) -> None:
    job, *rest = argv
    if job == "modules":
        (third_party,) = _forked([(_import_all, rest)])
        for name in third_party:  # what a fresh interpreter loads for them anyway
            try:
                importlib.import_module(name)
            except BaseException:  # left to the child that needs it to report
                pass
        ours = [name for name in sys.modules if _ours(name)]
        if ours:
            raise SystemExit(f"a third-party module imported observer-gym: {ours}")
        errors = _forked([(_import, module) for module in rest])
        print(json.dumps(dict(zip(rest, errors, strict=True))))
    elif job == "cli":
        heavy, *argvs = (json.loads(text) for text in rest)
        importlib.import_module("observer_gym.train.cli")
        loaded = _heavy_loaded(heavy)
        if loaded:
            raise SystemExit(f"importing the command imported {loaded}")
        print(json.dumps(_forked([(_run_command, argv, heavy) for argv in argvs])))
    else:
        raise SystemExit(f"unknown job {job!r}; choose modules or cli")


if __name__ == "__main__":
    main(sys.argv[1:])
