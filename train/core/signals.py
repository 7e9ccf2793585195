"""Ctrl-C (SIGINT) and ``kill`` (SIGTERM): a write in progress finishes before either
stops a command, and both stop it the same way.

Python runs a signal's handler in the main thread, between two bytecodes, wherever that
thread is; a ``KeyboardInterrupt`` raised inside ``torch.save``'s zip writer leaves a
broken temp file and a second error from the writer's cleanup. :func:`signals_deferred`
therefore records SIGINT and SIGTERM while a write runs and hands each, once the write
and its rename are done, to the handler that was in place before: Python's for SIGINT
(``KeyboardInterrupt``), :func:`sigterm_as_interrupt`'s for SIGTERM (the same), or the
default action (the process ends). Every atomic writer of
:mod:`observer_gym.train.reports.outputs` writes inside it, so a signal never lands in a
checkpoint, a results file or a sweep's cell. Ray cancels a task with a SIGINT to its
worker's main thread (``_thread.interrupt_main``), which waits likewise.

Outside the main thread the context does nothing: no handler can run there. Worker
processes (SubprocVecEnv's, the episode pools, Ray's) write no output files.

Written by hand: the standard library has no deferral, and Ray's (``DeferSigint``) is
private and defers SIGINT only.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

DEFERRED = (signal.SIGINT, signal.SIGTERM)
# The exit code of a command stopped by SIGINT or SIGTERM (128 + SIGINT, as a shell reports
# a Ctrl-C): the same for both, as 'observer-gym train' has always done.
INTERRUPTED_EXIT_CODE = 130


def _deliver(signum: int, handler: Callable[[int, Any], Any] | int | None) -> None:
    """What ``signum`` would have done under ``handler`` (already restored as the
    signal's handler): call it, ignore it, or take the default action."""
    if callable(handler):
        handler(signum, None)
    elif handler != signal.SIG_IGN:  # SIG_DFL, or a handler not set from Python
        signal.raise_signal(signum)


@contextmanager
def signals_deferred() -> Iterator[None]:
    """SIGINT and SIGTERM that arrive in the block are held until it ends, then handed
    (each once, in order of arrival) to the handlers that were in place: the block's work
    is never cut in half by them. Nests (an inner block hands its signals to the outer
    one). A no-op outside the main thread."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[int] = []

    def record(signum: int, frame: Any) -> None:
        received.append(signum)

    previous: dict[int, Any] = {}
    signum: int
    try:
        for signum in DEFERRED:
            if signal.getsignal(signum) is not None:  # None: set outside Python, kept
                previous[signum] = signal.signal(signum, record)
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        for signum in dict.fromkeys(received):
            _deliver(signum, previous[signum])


@contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """SIGTERM raises ``KeyboardInterrupt`` in the block, as Ctrl-C does, so that both stop
    a command the same way (outside the main thread: signals are left alone)."""

    def handler(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt(f"signal {signum}")

    try:
        previous = signal.signal(signal.SIGTERM, handler)
    except ValueError:  # not the main thread
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
