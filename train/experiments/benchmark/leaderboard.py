"""The leaderboard of a benchmark suite, generated from published results folders.

A published folder is the part of a finished, official ``observer-gym benchmark`` folder
that its scores rest on: ``episodes.csv``, ``scores.json`` and ``table.md``
(:data:`PUBLISHED`; no level files, timing or plot). They live under one root per suite
version, one folder per system and entry: ``docs/results/benchmark/v1/ball_table/
kf-measurements--lqr/``. Two commands::

    # copy finished runs' published files into the root (each checked first)
    python -m observer_gym.train.experiments.benchmark.leaderboard publish RUN_DIR... \\
        --into docs/results/benchmark/v1
    # docs/leaderboard.md and one figure per system from every folder under the root
    python -m observer_gym.train.experiments.benchmark.leaderboard generate \\
        docs/results/benchmark/v1 --out docs/leaderboard.md --figures docs/results/img

``generate`` re-derives every folder's scores from its episodes and the suite, as
``benchmark --check`` does (:func:`~observer_gym.train.experiments.benchmark.check.
check_folder`), except that a row's package versions may differ from this installation's
(rows span releases: the table shows the observer-gym version each was measured with),
and refuses an unofficial folder. The page ranks each system's entries by their IQM over
the levels; the figure draws the intervals with rliable's ``plot_interval_estimates``,
the one use of rliable left (optional: ``pip install 'observer-gym[rl]'``; without it
``generate`` stops with one line before it reads or writes anything; ``publish`` and the
scores need none).
Mistakes are one line on stderr and exit code 2; a folder that does not check out is one
line and exit code 1.
"""

from __future__ import annotations

import argparse
import html
import re
import shutil
import sys
import urllib.parse
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

from observer_gym.envs.json_file import read_json
from observer_gym.train.core.atomic_write import WriteError, replace_atomically
from observer_gym.train.experiments.benchmark.check import FolderCheckError, check_folder
from observer_gym.train.experiments.benchmark.records import EPISODES_CSV
from observer_gym.train.experiments.benchmark.report import SCORES_JSON, TABLE_MD
from observer_gym.train.experiments.benchmark.suite import SystemSuite, load_suite
from observer_gym.train.reports.outputs import output_set, write_text_atomic

PUBLISHED = (EPISODES_CSV, SCORES_JSON, TABLE_MD)
PROG = "python -m observer_gym.train.experiments.benchmark.leaderboard"
AGENT_PREFIXES = ("ppo:", "sac:", "td3:")
# the observer families (a name without its -measurements suffix) of the kinds other than
# classical: those that read the simulator's truth, and the learned ones
# (estimation/<system>/learned*.py, docs/learned_observers.md)
TRUE_STATE_OBSERVERS = ("oracle", "oracle-visible")
LEARNED_OBSERVERS = ("learned", "learned-kf")
# An entry's observer or controller name on the leaderboard: a built-in or installed name
# (kf-measurements, lqr), an import path (package.module:factory) or an agent
# (ppo:NAME, ppo:runs/x): letters, digits and _ . : / + = , @ -, at most 120 characters,
# so a published folder's name (observer--controller) stays under the file systems' 255.
ENTRY_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.:/+=,@-]{0,119}")
ENTRY_NAME_RULE = (
    "letters, digits and _ . : / + = , @ -, starting with a letter or digit, at most 120 characters"
)


class EntryNameError(FolderCheckError):
    """A results folder whose observer or controller name is no entry name
    (:data:`ENTRY_NAME`): the command line says so in one line, exit code 2."""


def check_entry_names(doc: dict[str, Any], path: Path) -> None:
    """:class:`EntryNameError` naming the first of ``doc``'s observer and controller that
    is no entry name (:data:`ENTRY_NAME`), and what names may hold."""
    for key in ("observer", "controller"):
        name = doc.get(key)
        if not isinstance(name, str) or ENTRY_NAME.fullmatch(name) is None:
            shown = (
                repr(name)
                if not isinstance(name, str) or len(name) <= 60
                else (f"{name[:57]!r}... ({len(name)} characters)")
            )
            raise EntryNameError(f"{path}: {key} {shown} is no entry name: {ENTRY_NAME_RULE}")


def _printable(text: str) -> str:
    """``text`` with its line breaks and other unprintable characters as escapes (\\n)."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def code_span(text: str, table: bool = False) -> str:
    """``text`` as a Markdown code span that shows it as it is: fenced by one backtick
    more than its longest run of backticks (CommonMark), its line breaks and other control
    characters shown as escapes, and with ``table`` ``|`` escaped for a table cell
    (GitHub's tables split on it even inside a span). Written by hand: no Markdown
    library is a dependency, and the rule is these three lines."""
    text = _printable(text)
    text = text.replace("|", "\\|") if table else text
    fence = "`" * (1 + max((len(run) for run in re.findall("`+", text)), default=0))
    pad = " " if text.startswith("`") or text.endswith("`") else ""
    return f"{fence}{pad}{text}{pad}{fence}"


def plain(text: str) -> str:
    """``text`` as plain Markdown text: HTML escaped, Markdown's special characters
    backslash-escaped, control characters shown as escapes."""
    text = _printable(str(text))
    return re.sub(r"([\\`*_{}\[\]()#+!|~>-])", r"\\\1", html.escape(text, quote=False))


class Row(NamedTuple):
    """One entry of the leaderboard: what ``scores.json`` says about it."""

    folder: Path
    suite: str  # "v1"
    env: str  # "observer_gym/BallTable-v0"
    observer: str
    controller: str
    command: str
    levels: tuple[tuple[str, float, float, float], ...]  # (level, score, low, high)
    iqm: tuple[float, float, float]  # (iqm, low, high)
    version: str  # observer-gym's, as recorded
    # the env options its episodes had beyond each level's: a trained agent's, travelled
    # from its training (scores.json's agent_env_options), and those its observer needs
    # (observer_env_options); empty for most entries
    agent_env_options: Mapping[str, Any] = {}
    observer_env_options: Mapping[str, Any] = {}

    @property
    def entry(self) -> str:
        return f"{self.observer} + {self.controller}"

    @property
    def kind(self) -> str:
        """``agent`` (a trained policy), ``true state`` (an observer that reads the
        simulator's truth: ``oracle``, ``oracle-visible``), ``learned`` (a learned observer
        on the camera, ``learned``, ``learned-kf``, and a designed controller) or
        ``classical`` (any other observer on the camera and a designed controller)."""
        if self.controller.startswith(AGENT_PREFIXES):
            return "agent"
        family = self.observer.removesuffix("-measurements")
        if family in TRUE_STATE_OBSERVERS:
            return "true state"
        if family in LEARNED_OBSERVERS:
            return "learned"
        return "classical"


def slug(observer: str, controller: str) -> str:
    """A published folder's name: ``kf-measurements--lqr``, ``kf-measurements--ppo-NAME``."""
    return f"{observer}--{controller}".replace(":", "-").replace("/", "_")


def _read(folder: Path) -> dict[str, Any]:
    try:
        doc = read_json(folder / SCORES_JSON)
    except (OSError, ValueError) as exc:
        raise FolderCheckError(f"{folder / SCORES_JSON} cannot be read: {exc}") from None
    if not isinstance(doc, dict):
        raise FolderCheckError(f"{folder / SCORES_JSON} is not a benchmark's scores")
    return doc


def _suite_of(doc: dict[str, Any], folder: Path) -> SystemSuite:
    try:
        return load_suite(str(doc["env"]), str(doc["suite"]))
    except (KeyError, ValueError) as exc:
        raise FolderCheckError(f"{folder}: {exc}") from None


def publish(run_dir: str | Path, root: str | Path, *, same_packages: bool = True) -> Path:
    """Copy a finished, official benchmark folder's published files into
    ``root/<system>/<slug>/`` (replacing an older copy); the folder written.
    ``same_packages``: as :func:`~observer_gym.train.experiments.benchmark.check.
    check_folder` takes it (publish what this installation ran).

    The files are copied into a staging folder beside the copy they replace and renamed
    over it (:func:`~observer_gym.train.reports.outputs.output_set`): a full disk leaves
    the earlier copy whole.

    Raises:
        EntryNameError: its observer or controller is no entry name (:data:`ENTRY_NAME`).
        FolderCheckError: the folder does not check out (see ``benchmark --check``), or
            is unofficial.
        WriteError: the copy cannot be written (a full disk); the earlier copy is kept.
    """
    run_dir = Path(run_dir)
    check_entry_names(_read(run_dir), run_dir / SCORES_JSON)  # before the names are used
    check_folder(run_dir, same_packages=same_packages)
    doc = _read(run_dir)
    if not doc.get("official"):
        raise FolderCheckError(f"{run_dir} is an unofficial run (--episodes): not published")
    suite = _suite_of(doc, run_dir)
    dest = Path(root) / suite.system.name / slug(doc["observer"], doc["controller"])
    try:
        dest.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise WriteError(f"could not write {dest}: {exc.strerror or exc}") from exc
    # staged beside the copy it replaces and renamed over it: a full disk leaves it whole
    with output_set(dest, last=(SCORES_JSON,)) as staging:
        for name in PUBLISHED:
            try:
                shutil.copyfile(run_dir / name, staging / name)
            except OSError as exc:
                raise WriteError(f"could not write {dest / name}: {exc.strerror or exc}") from exc
    return dest


def read_rows(root: str | Path, *, verify: bool = True) -> list[Row]:
    """Every published folder under ``root`` (``root/<system>/<entry>/scores.json``), in
    path order; with ``verify``, each re-derived from its episodes first.

    Raises:
        FolderCheckError: a folder does not check out, is unofficial, or belongs to
            another suite version than the root's other folders.
    """
    rows: list[Row] = []
    versions: set[str] = set()
    entries: dict[tuple[str, str, str], Path] = {}
    for path in sorted(Path(root).glob(f"*/*/{SCORES_JSON}")):
        folder = path.parent
        doc = _read(folder)
        check_entry_names(doc, path)  # before anything else reads the names
        if verify:
            check_folder(folder, same_packages=False)
        if not doc.get("official"):
            raise FolderCheckError(f"{folder} is an unofficial run: a leaderboard has none")
        expected = (
            f"{_suite_of(doc, folder).system.name}/{slug(doc['observer'], doc['controller'])}"
        )
        if f"{folder.parent.name}/{folder.name}" != expected:
            raise FolderCheckError(
                f"{folder} holds {doc['observer']} + {doc['controller']}, whose published "
                f"folder is {Path(root) / expected}: move it there ('publish' names it so)"
            )
        key = (str(doc["env"]), doc["observer"], doc["controller"])
        if key in entries:
            raise FolderCheckError(
                f"{folder} and {entries[key]} hold the same entry, {key[1]} + {key[2]}: keep one"
            )
        entries[key] = folder
        versions.add(str(doc.get("suite")))
        if len(versions) > 1:
            raise FolderCheckError(
                f"{folder}: suite versions {sorted(versions)} under one root; one per root"
            )
        rows.append(
            Row(
                folder=folder,
                suite=str(doc["suite"]),
                env=doc["env"],
                observer=doc["observer"],
                controller=doc["controller"],
                command=doc["command"],
                levels=tuple(
                    (lv["level"], lv["score"], lv["score_low"], lv["score_high"])
                    for lv in doc["levels"]
                ),
                iqm=(doc["aggregate"]["iqm"], doc["aggregate"]["low"], doc["aggregate"]["high"]),
                version=doc["packages"].get("observer-gym", "?"),
                agent_env_options=dict(doc.get("agent_env_options") or {}),
                observer_env_options=dict(doc.get("observer_env_options") or {}),
            )
        )
    return rows


def _by_env(rows: Sequence[Row]) -> dict[str, list[Row]]:
    """Rows grouped by env (in env order), each group ranked by IQM, best first (ties by
    entry name)."""
    groups: dict[str, list[Row]] = {}
    for row in sorted(rows, key=lambda r: r.env):
        groups.setdefault(row.env, []).append(row)
    return {env: sorted(group, key=lambda r: (-r.iqm[0], r.entry)) for env, group in groups.items()}


def _cell(score: float, low: float, high: float) -> str:
    return f"{score:.3f} [{low:.3f}, {high:.3f}]"


def _options_cell(row: Row) -> str:
    """The env options a row's episodes had beyond each level's: the agent's, travelled
    from its training (``agent: ...``), and those its observer needs (``observer: ...``);
    "none" without."""
    parts = [
        f"{who}: " + code_span(", ".join(f"{k}={v!r}" for k, v in options.items()), table=True)
        for who, options in (("agent", row.agent_env_options),
                             ("observer", row.observer_env_options))
        if options
    ]  # fmt: skip
    return "; ".join(parts) or "none"


def figure_name(suite: SystemSuite) -> str:
    return f"leaderboard_{suite.version}_{suite.system.name}.png"


def markdown(rows: Sequence[Row], root: str, figures_dir: str, command: str) -> str:
    """docs/leaderboard.md's text. ``root`` and ``figures_dir`` are written as given
    (paths relative to the page)."""
    if not rows:
        raise FolderCheckError(f"no published benchmark folders under {root}")
    groups = _by_env(rows)
    version = rows[0].suite
    command = _printable(command)
    fence = "`" * max(3, 1 + max((len(run) for run in re.findall("`+", command)), default=0))
    figures_dir = urllib.parse.quote(figures_dir, safe="/._-~")
    lines = [
        f"# Leaderboard: observer-gym benchmark suite {version}",
        "",
        "Generated; do not edit by hand. Every row is an official run of `observer-gym "
        "benchmark` (the protocol, the levels and the normalised score: "
        "[benchmark.md](benchmark.md)), re-derived from its per-episode records by the "
        "command that wrote this page:",
        "",
        fence,
        command,
        fence,
        "",
        f"The results folders: {code_span(f'{root}/<system>/<entry>/')} (`episodes.csv`, "
        "`scores.json`, "
        "`table.md`). Scores: 1 = the oracle observer with the system's reference "
        "controller, 0 = the floor (the worse of the raw camera and doing nothing); each "
        "level's mean score and the IQM over the levels, with their 95 % bootstrap "
        "intervals. Entries are ranked by the IQM; two entries whose intervals overlap are "
        "not told apart by this suite. Kinds: `classical` is an observer on the camera with a "
        "designed controller, `learned` a learned observer on the camera (`learned`, "
        "`learned-kf`: a network that maps the newest frames' detections to the state, alone "
        "or as a Kalman filter's measurement model; "
        "[learned_observers.md](learned_observers.md)) with a designed controller, "
        "`agent` a trained policy (train/rl/agents/), `true state` an "
        "observer that reads the simulator's truth, for analysis: `oracle` (no camera; "
        "with the reference controller 1 by definition) and `oracle-visible` (the truth "
        "while the camera sees the target, predicted otherwise). Env options: what a row's "
        "episodes had beyond each level's options, a trained agent's own (its camera and "
        "its reward's weights, the options that travel with it to every level) and those "
        "its observer needs.",
        "",
    ]
    for env, group in groups.items():
        suite = load_suite(env, version)
        level_names = [name for name, *_ in group[0].levels]
        short = env.split("/")[-1]
        lines += [
            f"## {short}",
            "",
            f"Metric per episode: `{suite.metric.name}` ({suite.metric.better} is better); "
            f"reference controller `{suite.controller}`; {suite.episodes} episodes per level.",
            "",
        ]
        header = ["rank", "observer", "controller", "kind", "env options", *level_names,
                  "IQM [95 %]", "version"]  # fmt: skip
        table = [header, ["---"] * len(header)]
        for rank, row in enumerate(group, start=1):
            table.append(
                [
                    str(rank),
                    code_span(row.observer, table=True),
                    code_span(row.controller, table=True),
                    row.kind,
                    _options_cell(row),
                    *(_cell(s, lo, hi) for _, s, lo, hi in row.levels),
                    _cell(*row.iqm),
                    plain(row.version),
                ]
            )
        lines += ["| " + " | ".join(cells) + " |" for cells in table]
        lines += [
            "",
            f"![{short}: interval estimates per level and of the IQM]"
            f"({figures_dir}/{figure_name(suite)})",
            "",
            "Commands, by rank:",
            "",
        ]
        lines += [f"{rank}. {code_span(row.command)}" for rank, row in enumerate(group, start=1)]
        lines.append("")
    return "\n".join(lines)


FIGURES_INSTALL_HINT = "pip install 'observer-gym[rl]'"


def figures_problem() -> str | None:
    """Why the figures cannot be drawn here (rliable's plotting cannot be imported), in
    one line naming the pip command; None if they can."""
    try:
        from rliable import plot_utils  # noqa: F401  (arch, pandas < 3, seaborn)
    except ImportError as exc:
        return (
            f"the leaderboard's figures are drawn with rliable, which is not installed or "
            f"broken ({exc}): {FIGURES_INSTALL_HINT}"
        )
    return None


def draw_figures(rows: Sequence[Row], figures_dir: Path) -> list[Path]:
    """One PNG per system: each entry's level scores and IQM with their intervals
    (rliable's ``plot_interval_estimates``); the files written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from rliable import plot_utils

    written = []
    try:
        figures_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise WriteError(f"could not write {figures_dir}: {exc.strerror or exc}") from exc
    for env, group in _by_env(rows).items():
        suite = load_suite(env, group[0].suite)
        metrics = [name for name, *_ in group[0].levels] + ["IQM"]
        points = {}
        intervals = {}
        for row in group:
            triples = [(s, lo, hi) for _, s, lo, hi in row.levels] + [row.iqm]
            points[row.entry] = np.array([t[0] for t in triples])
            intervals[row.entry] = np.array([[t[1] for t in triples], [t[2] for t in triples]])
        fig, axes = plot_utils.plot_interval_estimates(
            points,
            intervals,
            metric_names=metrics,
            algorithms=[row.entry for row in group][::-1],
            xlabel=f"normalised score, {env.split('/')[-1]}",
            subfigure_width=3.0,
            row_height=0.32,
            xlabel_y_coordinate=-0.6 / (0.32 * len(group)),
        )
        # one range on every panel, 0 (floor) and 1 (oracle) always in view
        lowest = min(0.0, *(float(iv[0].min()) for iv in intervals.values()))
        highest = max(1.0, *(float(iv[1].max()) for iv in intervals.values()))
        for ax in np.atleast_1d(axes):
            ax.set_xlim(lowest - 0.03, highest + 0.03)
            ax.axvline(1.0, color="grey", lw=0.8, ls="--")
        path = figures_dir / figure_name(suite)

        def save(tmp: Path, fig: Any = fig) -> None:
            fig.savefig(tmp, format="png", dpi=100, bbox_inches="tight")

        try:
            replace_atomically(path, save)
        finally:
            plt.close(fig)
        written.append(path)
    return written


NAME_MAX_BYTES = 255  # a file name's longest on Linux, macOS and Windows file systems


def path_problem(text: str) -> str | None:
    """Why ``text`` cannot name a file (a NUL character, a name longer than
    :data:`NAME_MAX_BYTES` bytes), in one line; None if it can."""
    if "\0" in text:
        return f"{text!r} contains a NUL character, which no file name holds"
    long = [part for part in Path(text).parts if len(part.encode()) > NAME_MAX_BYTES]
    if long:
        return (
            f"{long[0][:40]!r}... ({len(long[0].encode())} bytes) is longer than a file "
            f"name can be ({NAME_MAX_BYTES} bytes)"
        )
    return None


def generate_command(root: str, out: str, figures: str) -> str:
    """The command that writes the page, as the page quotes it."""
    return f"{PROG} generate {root} --out {out} --figures {figures}"


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    pub = commands.add_parser("publish", help="copy finished official runs into a results root")
    pub.add_argument("runs", nargs="+", metavar="RUN_DIR", help="finished benchmark folders")
    pub.add_argument("--into", required=True, metavar="ROOT", help="the suite's results root")
    gen = commands.add_parser("generate", help="write the leaderboard page and its figures")
    gen.add_argument("root", metavar="ROOT", help="the suite's results root")
    gen.add_argument("--out", required=True, metavar="FILE", help="the Markdown page to write")
    gen.add_argument("--figures", required=True, metavar="DIR", help="where the PNGs go")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """``publish`` or ``generate`` (see the module docstring); the exit code."""
    import os

    from observer_gym.train.core.messages import error_line

    args = _parser().parse_args(argv)
    paths = [*args.runs, args.into] if args.command == "publish" else [args.root, args.out]
    paths += [args.figures] if args.command == "generate" else []
    for text in paths:
        problem = path_problem(text)
        if problem:
            print(error_line(PROG, problem), file=sys.stderr)
            return 2
    try:
        if args.command == "publish":
            for run_dir in args.runs:
                print(publish(run_dir, args.into))
            return 0
        root = Path(args.root)
        if not root.is_dir():
            print(error_line(PROG, f"{root} is not a folder"), file=sys.stderr)
            return 2
        problem = figures_problem()
        if problem:  # before anything is read or written
            print(error_line(PROG, problem), file=sys.stderr)
            return 2
        out = Path(args.out)
        figures = Path(args.figures)
        rows = read_rows(root)
        command = generate_command(args.root, args.out, args.figures)
        page_dir = out.parent
        text = markdown(
            rows,
            os.path.relpath(root, page_dir),
            os.path.relpath(figures, page_dir),
            command,
        )
        draw_figures(rows, figures)
        write_text_atomic(out, text)
        print(f"{out}: {len(rows)} entries; figures in {figures}")
        return 0
    except EntryNameError as exc:
        print(error_line(PROG, exc), file=sys.stderr)
        return 2
    except FolderCheckError as exc:
        print(error_line(PROG, exc), file=sys.stderr)
        return 1
    except OSError as exc:  # a full disk, no permission: WriteError names the file
        message = str(exc) if isinstance(exc, WriteError) else f"{exc.strerror or exc}"
        if not isinstance(exc, WriteError) and exc.filename:
            message = f"{exc.filename}: {message}"
        print(error_line(PROG, message), file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
