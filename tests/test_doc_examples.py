"""Every code block of README.md and docs/*.md runs as written (or shortened where the doc
marks it), and every output a doc quotes is what its block prints (issue 42). The markup
is read by tests/doc_blocks.py, which says what each marker means."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from doc_blocks import DOCS, ROOT, RUNNABLE, all_blocks, quoted_by, quotes, read_blocks

BLOCKS = all_blocks()
OUTPUTS = [b for b in BLOCKS if b.output]
QUOTED = {quoted_by(read_blocks(o.path)[0], o) for o in OUTPUTS}
# README.md's python blocks run in tests/test_readme_examples.py (which also checks that
# every printed line is labelled), and here too those whose output the README quotes;
# every other runnable block that no marker skips runs here:
TO_RUN = [
    b
    for b in BLOCKS
    if b.language in RUNNABLE
    and b.skip is None
    and (b.path.name != "README.md" or b.language != "python" or b in QUOTED)
]
LINKED = ("examples", "benchmarks", "docs")


@pytest.mark.parametrize("path", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_block_says_how_it_runs(path):
    blocks, problems = read_blocks(path)
    assert not problems, "\n".join(problems)
    for output in (b for b in blocks if b.output):
        source = quoted_by(blocks, output)
        assert source is not None, f"{output.name}: quotes the output of no block before it"
        assert source.skip is None and not source.replacements, (
            f"{output.name}: quotes {source.name}, which the test does not run as written"
        )


def run_block(block, tmp_path: Path) -> str:
    """What ``block`` prints (stdout and stderr), run in ``tmp_path``; fails on an error
    (on any exit status but the expected one, for a block of refusals)."""
    for name in LINKED:
        (tmp_path / name).symlink_to(ROOT / name)
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    env["MPLBACKEND"] = "Agg"
    if block.language == "python":
        runs = [([sys.executable, "-c", block.to_run()], 0)]
    elif block.fails is not None:
        runs = [(["bash", "-c", command], block.fails) for command in block.commands()]
    else:
        runs = [(["bash", "-e", "-o", "pipefail", "-c", block.to_run()], 0)]
    printed = ""
    for command, status in runs:
        result = subprocess.run(
            command, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900
        )
        out = result.stdout + result.stderr
        assert result.returncode == status, (
            f"{block.name}: {command[-1][:200]!r} exited {result.returncode}, "
            f"not {status}:\n{out[-3000:]}"
        )
        printed += out
    return printed


@pytest.mark.slow
@pytest.mark.parametrize("block", TO_RUN, ids=lambda b: b.name)
def test_block_runs_and_prints_what_the_doc_quotes(block, tmp_path):
    printed = run_block(block, tmp_path)
    quoted = [o for o in OUTPUTS if o.path == block.path and quoted_by(all_in(o.path), o) == block]
    lines = printed.splitlines()
    for output in quoted:
        position = 0
        for expected in filter(str.strip, output.code.splitlines()):
            found = [i for i in range(position, len(lines)) if quotes(lines[i], expected)]
            assert found, (
                f"{output.name} quotes {expected!r}, which {block.name} does not print "
                f"(after the lines matched so far); it printed:\n{shown(lines)}"
            )
            position = found[0] + 1


def shown(lines: list[str]) -> str:
    """The printed lines without the progress bars' (on stderr, a line per update)."""
    return "\n".join(line for line in lines if "it/s]" not in line and "/s]" not in line)[-4000:]


def all_in(path: Path):
    return read_blocks(path)[0]
