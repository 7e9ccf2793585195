"""The optional ``[rl]`` extra and the error for its absence.

``pip install observer-gym`` (the core install) has no PyTorch: the envs, the classical
observers and controllers, ``run``/``compare``/``sweep``/``benchmark`` of those, ``list``
and ``demo``. ``pip install 'observer-gym[rl]'`` adds stable-baselines3 and PyTorch:
``train``, ``evaluate``, trained agents as controllers (``ppo:DIR``, ``ALGO:PATH.zip``)
and the learned observers (``learned``, ``learned-kf`` and their ``-measurements``).
What needs them calls :func:`require_rl` before importing them, so a core install
refuses it with :class:`ExtraNotInstalled` naming the install line, before any env is
built; the command line prints that as one line with exit code 2. Nothing the core
commands import imports torch or stable-baselines3 (tests/test_light_install.py).

Whether a module is installed is asked of the import system (``importlib.util.find_spec``),
which imports nothing: finding PyTorch costs microseconds, importing it about a second.
"""

from __future__ import annotations

import importlib.util
import sys
from collections.abc import Iterable

RL_INSTALL = "pip install 'observer-gym[rl]'"
# ``--video`` (observer_gym.train.reports.video) streams frames to ffmpeg through these
VIDEO_INSTALL = "pip install 'observer-gym[video]'"
VIDEO_MODULES = ("imageio", "imageio_ffmpeg")
# ``observer-gym record`` (observer_gym.train.reports.dataset) writes Minari datasets:
# Minari's DataCollector needs JAX's tree utilities and h5py (minari[create,hdf5])
RECORD_INSTALL = "pip install 'observer-gym[record]'"
RECORD_MODULES = ("minari", "jax", "h5py")
# ``--rerun FILE.rrd`` (observer_gym.train.reports.rerun_recording) writes a recording
# for the rerun viewer with rerun-sdk
RERUN_INSTALL = "pip install 'observer-gym[rerun]'"
RERUN_MODULES = ("rerun",)
# what a trained agent (stable-baselines3) needs; a learned observer needs torch only
AGENT_MODULES = ("stable_baselines3", "torch")
TORCH_MODULES = ("torch",)
# the distributions' names, as a user installs them
_SHOWN = {
    "torch": "PyTorch",
    "stable_baselines3": "stable-baselines3",
    "imageio_ffmpeg": "imageio-ffmpeg",
    "rerun": "rerun-sdk",
}


class ExtraNotInstalled(ImportError):
    """What was asked for needs an extra (``[rl]``: PyTorch, stable-baselines3;
    ``[video]``: imageio, imageio-ffmpeg; ``[record]``: minari; ``[rerun]``: rerun-sdk)
    that is not installed; the message names the install line.

    An ImportError, as the failed import itself would be (code that tolerates a missing
    optional dependency catches ImportError), not a ValueError: the request is valid, the
    installation lacks a part. ``name`` is the first missing module.
    """


def missing_modules(modules: Iterable[str]) -> list[str]:
    """The top-level modules of ``modules`` that cannot be imported here (not installed,
    or refused by an import hook), without importing any."""
    missing = []
    for module in modules:
        if module in sys.modules:
            continue
        try:
            found = importlib.util.find_spec(module) is not None
        except (ImportError, ValueError):
            found = False
        if not found:
            missing.append(module)
    return missing


def require_rl(what: str, modules: Iterable[str] = AGENT_MODULES) -> None:
    """Raise :class:`ExtraNotInstalled` unless every module of ``modules`` is installed;
    ``what`` (``"observer 'learned'"``, ``"observer-gym train"``) begins the message:
    "observer 'learned' needs PyTorch, which is not installed: pip install
    'observer-gym[rl]'"."""
    _require(what, modules, RL_INSTALL)


def require_video(what: str = "--video") -> None:
    """Raise :class:`ExtraNotInstalled` unless the ``[video]`` extra (imageio,
    imageio-ffmpeg) is installed: "--video needs imageio-ffmpeg, which is not installed:
    pip install 'observer-gym[video]'"."""
    _require(what, VIDEO_MODULES, VIDEO_INSTALL)


def require_record(what: str = "observer-gym record") -> None:
    """Raise :class:`ExtraNotInstalled` unless the ``[record]`` extra (minari with JAX and
    h5py) is installed: "observer-gym record needs minari, which is not installed: pip
    install 'observer-gym[record]'"."""
    _require(what, RECORD_MODULES, RECORD_INSTALL)


def require_rerun(what: str = "--rerun") -> None:
    """Raise :class:`ExtraNotInstalled` unless the ``[rerun]`` extra (rerun-sdk) is
    installed: "--rerun needs rerun-sdk, which is not installed: pip install
    'observer-gym[rerun]'"."""
    _require(what, RERUN_MODULES, RERUN_INSTALL)


def _require(what: str, modules: Iterable[str], install: str) -> None:
    missing = missing_modules(modules)
    if missing:
        names = " and ".join(_SHOWN.get(module, module) for module in missing)
        verb = "is" if len(missing) == 1 else "are"
        raise ExtraNotInstalled(
            f"{what} needs {names}, which {verb} not installed: {install}", name=missing[0]
        )
