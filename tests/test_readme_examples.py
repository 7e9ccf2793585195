"""Every Python example in the README runs as written and prints labelled output."""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
BLOCKS = re.findall(r"```python\n(.*?)```", README.read_text(), re.S)


@pytest.mark.slow
@pytest.mark.parametrize("index", range(len(BLOCKS)))
def test_readme_example_runs_and_prints(index):
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        exec(compile(BLOCKS[index], f"README.md python block {index}", "exec"), {})
    lines = [line for line in printed.getvalue().splitlines() if line.strip()]
    assert lines, "the example prints nothing"
    # Labelled output: every printed line says what it is, not a bare tuple or array.
    for line in lines:
        assert not line.lstrip().startswith(("(", "[")), line
