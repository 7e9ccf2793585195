"""PyBullet, imported once for the whole package with its start-up chatter silenced.

Every module of observer_gym.envs takes ``pybullet`` from here: the first
``import pybullet`` writes a "pybullet build time" line to stderr (dropped here; anything
else it writes passes on), and every ``connect`` an "argv[0]=" line to stdout
(:func:`silenced` hides such C-level writes).
"""

from __future__ import annotations

import contextlib
import functools
import os
import sys
import tempfile


@contextlib.contextmanager
def silenced(fd: int):
    """Silence C-level writes to file descriptor ``fd`` (1: stdout, 2: stderr) inside the
    block."""
    stream = sys.stdout if fd == 1 else sys.stderr
    try:
        stream.flush()
        saved = os.dup(fd)
    except (OSError, ValueError, AttributeError):  # no real stream: nothing to hide
        yield
        return
    try:
        with open(os.devnull, "w") as devnull:
            os.dup2(devnull.fileno(), fd)
            yield
    finally:
        os.dup2(saved, fd)
        os.close(saved)


def _import_without_banner():
    """Import PyBullet with file descriptor 2 captured; write back all but the banner."""
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):  # no real stderr: nothing to filter
        import pybullet

        return pybullet
    with tempfile.TemporaryFile() as capture:
        os.dup2(capture.fileno(), 2)
        try:
            import pybullet
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            capture.seek(0)
            written = capture.read().decode(errors="replace").splitlines(keepends=True)
            rest = [line for line in written if not line.startswith("pybullet build time:")]
            if rest:
                sys.stderr.write("".join(rest))
                sys.stderr.flush()
    return pybullet


pybullet = _import_without_banner()
import pybullet_data  # noqa: E402  (after pybullet's quiet import)
from pybullet_utils.bullet_client import BulletClient as _PybulletUtilsClient  # noqa: E402

__all__ = ["BulletClient", "pybullet", "pybullet_data", "silenced"]


class BulletClient(_PybulletUtilsClient):
    """pybullet_utils' BulletClient (every pybullet function with this client's
    ``physicsClientId``) that binds each function once: the original builds a new
    ``functools.partial`` and runs ``inspect.isbuiltin`` on every call, about 2.5 us, 7 %
    of a BallCatcher state-mode step (benchmarks/bench_envs.py). ``disconnect`` drops
    the bound functions, so a closed client's calls fail as the original's do instead of
    reaching a later client that PyBullet gave the same id."""

    def __getattr__(self, name: str):
        attribute = super().__getattr__(name)
        if name == "disconnect":
            for bound in [k for k, v in vars(self).items() if isinstance(v, functools.partial)]:
                del self.__dict__[bound]
        elif isinstance(attribute, functools.partial):
            self.__dict__[name] = attribute
        return attribute
