"""The code blocks of README.md and docs/*.md, with what each doc says about running them.

Every fenced block has a language: ``python`` runs as a script, ``bash`` runs in bash
(each in a fresh folder holding links to the repository's ``examples/``, ``benchmarks/``
and ``docs/``), ``text`` and ``toml`` are data and never run. An HTML comment right
before a block (blank lines between are allowed) says more:

- ``<!-- doc-test: skip: REASON -->``: a runnable block that the test does not run
  (installs packages, needs a cluster, writes tracked files, ...), and why;
- ``<!-- doc-test: replace: OLD => NEW -->`` (one comment each): the test runs the
  block with OLD replaced by NEW, for a command that would take minutes as written;
- ``<!-- doc-test: fails: CODE -->`` before a ``bash`` block of commands that each
  show a refusal: each command runs on its own and must exit with status CODE;
- ``<!-- doc-test: output -->`` before a ``text`` block or a Markdown table: its
  non-blank lines are printed, in this order, by the nearest runnable block before it,
  which must run unshortened; ``...`` in a quoted line stands for any text (as in
  doctest's ELLIPSIS). A quoted table is kept as a block of language ``table``.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = (ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")))
RUNNABLE = ("python", "bash")
DATA = ("text", "toml")
FENCE = re.compile(r"^```(\S*)\s*$")
# A generated page cannot carry markers (its generator rewrites it): its blocks are
# commands that the test does not run, for this reason.
GENERATED = {
    "leaderboard.md": "the page's own generating command, which rewrites the tracked page; "
    "tests/train/experiments/test_benchmark_leaderboard.py holds the page to that command's output"
}
MARKER = re.compile(r"^<!-- doc-test: (skip|replace|fails|output)(?:: (.*?))? -->$")


@dataclasses.dataclass(frozen=True)
class Block:
    path: Path
    line: int  # of the opening fence, 1-based
    language: str
    code: str
    skip: str | None = None  # the reason
    replacements: tuple[tuple[str, str], ...] = ()
    output: bool = False  # a quoted output of the runnable block before it
    fails: int | None = None  # each command's expected exit status

    @property
    def name(self) -> str:
        return f"{self.path.relative_to(ROOT)}:{self.line}"

    def to_run(self) -> str:
        code = self.code
        for old, new in self.replacements:
            code = code.replace(old, new)
        return code

    def commands(self) -> list[str]:
        """The shell commands of the block, continuation lines joined."""
        return [c for c in self.to_run().replace("\\\n", " ").splitlines() if c.strip()]


def quotes(printed: str, quoted: str) -> bool:
    """Whether ``printed`` has the line ``quoted``, ``...`` in it standing for any text."""
    pattern = ".*".join(map(re.escape, quoted.strip().split("...")))
    return any(re.fullmatch(pattern, line.strip()) for line in printed.splitlines())


def read_blocks(path: Path) -> tuple[list[Block], list[str]]:
    """The blocks of ``path`` and the problems of its markup (a block without a language,
    a marker that names nothing, a replacement that matches nothing, ...)."""
    lines = path.read_text().splitlines()
    blocks: list[Block] = []
    problems: list[str] = []
    markers: list[tuple[str, str | None]] = []
    i = 0
    while i < len(lines):
        text = lines[i].strip()
        marker = MARKER.match(text)
        fence = FENCE.match(lines[i])
        if marker:
            markers.append((marker.group(1), marker.group(2)))
        elif fence:
            end = i + 1
            while end < len(lines) and not lines[end].startswith("```"):
                end += 1
            where = f"{path.relative_to(ROOT)}:{i + 1}"
            language = fence.group(1)
            if path.name in GENERATED and not language:
                language, markers = "bash", [("skip", GENERATED[path.name])]
            kinds = [kind for kind, _ in markers]
            skip = next((arg for kind, arg in markers if kind == "skip"), None)
            replacements = []
            for kind, arg in markers:
                if kind == "replace":
                    old, sep, new = (arg or "").partition(" => ")
                    replacements.append((old, new))
                    if not sep or not old:
                        problems.append(f"{where}: a replace marker is 'OLD => NEW'")
            fails = next((arg for kind, arg in markers if kind == "fails"), None)
            if fails is not None and not fails.isdigit():
                problems.append(f"{where}: a fails marker names the exit status, got {fails!r}")
            block = Block(
                path,
                i + 1,
                language,
                "\n".join(lines[i + 1 : end]) + "\n",
                skip,
                tuple(replacements),
                "output" in kinds,
                int(fails) if fails and fails.isdigit() else None,
            )
            if fails is not None and language != "bash":
                problems.append(f"{where}: a fails marker is for a bash block")
            if language not in RUNNABLE + DATA:
                problems.append(
                    f"{where}: the block's language must be one of "
                    f"{', '.join(RUNNABLE + DATA)}, got {language!r}"
                )
            if "skip" in kinds and not skip:
                problems.append(f"{where}: a skip marker names its reason")
            if (skip or replacements) and language not in RUNNABLE:
                problems.append(f"{where}: skip and replace markers are for runnable blocks")
            if block.output and language != "text":
                problems.append(f"{where}: an output marker is for a text block or a table")
            for old, _ in replacements:
                if old and old not in block.code:
                    problems.append(f"{where}: {old!r} (to replace) is not in the block")
            blocks.append(block)
            markers = []
            i = end
        elif text.startswith("|") and ("output", None) in markers:
            end = i
            while end < len(lines) and lines[end].strip().startswith("|"):
                end += 1
            table = "\n".join(lines[i:end]) + "\n"
            blocks.append(Block(path, i + 1, "table", table, output=True))
            markers = []
            i = end - 1
        elif text:
            if markers:
                problems.append(f"{path.relative_to(ROOT)}:{i + 1}: a marker not before a block")
            markers = []
        i += 1
    return blocks, problems


def quoted_by(blocks: list[Block], output: Block) -> Block | None:
    """The runnable block whose output ``output`` quotes: the nearest one before it."""
    before = [b for b in blocks if b.line < output.line and b.language in RUNNABLE]
    return before[-1] if before else None


def all_blocks() -> list[Block]:
    return [block for path in DOCS for block in read_blocks(path)[0]]
