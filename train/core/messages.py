"""How ``observer_gym.train`` reports a mistake and a warning on a command line: one
line, ``PROG: error: MESSAGE`` (exit code 2) or ``PROG: warning: MESSAGE``, without
Python's traceback, file and line."""

from __future__ import annotations


class UsageError(SystemExit):
    """A mistake in the command line: exit code 2; ``str()`` is the message."""

    def __init__(self, message: str) -> None:
        super().__init__(2)
        self.message = message

    def __str__(self) -> str:
        return self.message


class OneLineWarning(UserWarning):
    """A warning the ``observer-gym`` command shows as one line,
    ``observer-gym COMMAND: warning: ...`` (without Python's file and line)."""


def one_line(text: object) -> str:
    """``text`` with every run of whitespace (newlines too) made one space."""
    return " ".join(str(text).split())


def error_line(prog: str, message: object) -> str:
    """The one line that reports a mistake: ``PROG: error: MESSAGE``."""
    return f"{prog}: error: {one_line(message)}"
