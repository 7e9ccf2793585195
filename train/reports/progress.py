"""Progress bars (tqdm) that draw on every terminal.

A pseudo-terminal that reports no size (0 x 0: ``script`` without a terminal, some
containers and CI runners) makes tqdm draw an empty bar: nothing shows for the whole
run. :func:`progress_bar` gives tqdm a size there (``COLUMNS`` / ``LINES``, else 80 x 24).
"""

from __future__ import annotations

import os
import shutil
import sys
from typing import Any

from tqdm import tqdm


def terminal_shape() -> dict[str, int]:
    """``ncols`` and ``nrows`` for tqdm when stderr's terminal reports no size; empty
    otherwise (tqdm reads the size itself)."""
    try:
        size = os.get_terminal_size(sys.stderr.fileno())
    except (OSError, ValueError, AttributeError):  # not a terminal, or no real stderr
        return {}
    if size.columns > 0 and size.lines > 0:
        return {}
    fallback = shutil.get_terminal_size()  # COLUMNS / LINES, else 80 x 24
    return {"ncols": fallback.columns, "nrows": fallback.lines}


def progress_bar(**kwargs: Any) -> tqdm:
    """``tqdm(**kwargs)``, with a size on a terminal that reports none."""
    return tqdm(**{**terminal_shape(), **kwargs})
