"""What the tests of damaged and hostile folders share: a full disk and a folder's bytes
(the tiny training run they damage is tests/conftest.py's ``tiny_run``)."""

from __future__ import annotations

import resource
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

STEPS = 64  # env steps per checkpoint of tests/conftest.py's tiny_run


@contextmanager
def file_size_limit(limit_bytes: int) -> Iterator[None]:
    """Writing past ``limit_bytes`` fails with EFBIG, as on a full disk (Python ignores
    SIGXFSZ)."""
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (hidden ones too; not links) and its bytes."""
    return {
        p.relative_to(folder).as_posix(): p.read_bytes()
        for p in folder.rglob("*")
        if p.is_file() and not p.is_symlink()
    }
