"""Worker processes end with the command that started them.

A command that is killed outright (SIGKILL, the out-of-memory killer) passes nothing on
to its worker processes: the episode pools of ``run``, ``compare``, ``sweep`` and
``benchmark`` would wait for work that never comes, and ``train --seeds``' seeds (each in
a process group of its own) would train on, holding their folders' locks. Each worker
therefore calls :func:`end_with_parent` first: a daemon thread waits on the parent's
sentinel (:func:`multiprocessing.parent_process`, ready when the parent has ended, on
every platform) and then sends this process SIGTERM, so the worker stops exactly as when
a live parent passes a signal on: a seed ends its run as an interrupted one (its last
checkpoint kept, ``state.json`` "interrupted", its lock released), an episode worker
ends.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import threading
from multiprocessing.connection import wait


def end_with_parent() -> None:
    """In a process started by :mod:`multiprocessing`: SIGTERM to this process as soon as
    its parent ends (a daemon thread waits for it). Does nothing in a process that
    :mod:`multiprocessing` did not start."""
    parent = multiprocessing.parent_process()
    if parent is None:
        return
    sentinel = parent.sentinel

    def watch() -> None:
        wait([sentinel])  # returns once the parent has ended (at once if it already has)
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=watch, name="end-with-parent", daemon=True).start()
