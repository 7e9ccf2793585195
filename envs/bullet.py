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
import threading

# The descriptors silenced now: fd -> [threads inside, the real descriptor's copy]. One
# swap per fd however many threads are inside (each entering thread would otherwise save
# /dev/null as "the real one" and restore it last), under a lock.
_SILENCED: dict[int, list] = {}
_SILENCED_LOCK = threading.Lock()


@contextlib.contextmanager
def silenced(fd: int):
    """Silence C-level writes to file descriptor ``fd`` (1: stdout, 2: stderr) inside the
    block. Thread-safe: the first thread in swaps ``fd`` to /dev/null, the last one out
    restores it; meanwhile every thread's writes to ``fd`` are silenced (a descriptor is
    the process's, not a thread's)."""
    stream = sys.stdout if fd == 1 else sys.stderr
    with _SILENCED_LOCK:
        state = _SILENCED.get(fd)
        if state is None:
            try:
                stream.flush()
                saved = os.dup(fd)
            except (OSError, ValueError, AttributeError):  # no real stream: nothing to hide
                saved = None
            if saved is not None:
                devnull = os.open(os.devnull, os.O_WRONLY)
                os.dup2(devnull, fd)
                os.close(devnull)
            state = _SILENCED[fd] = [0, saved]
        state[0] += 1
    try:
        yield
    finally:
        with _SILENCED_LOCK:
            state[0] -= 1
            if state[0] == 0:
                del _SILENCED[fd]
                if state[1] is not None:
                    os.dup2(state[1], fd)
                    os.close(state[1])


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
