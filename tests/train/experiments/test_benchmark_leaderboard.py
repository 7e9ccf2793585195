"""docs/leaderboard.md against the committed results folders it is generated from
(docs/results/benchmark/v1): the page is the generator's output, ranked by IQM, the
folders hold only the published files, a changed or unofficial folder is refused, and
(slow) every committed folder re-derives."""

from __future__ import annotations

import csv
import json
import shutil
import sys
from pathlib import Path

import pytest

from observer_gym.train.experiments.benchmark.check import FolderCheckError
from observer_gym.train.experiments.benchmark.leaderboard import (
    PUBLISHED,
    generate_command,
    main,
    markdown,
    publish,
    read_rows,
)

REPO = Path(__file__).resolve().parents[3]
ROOT = REPO / "docs" / "results" / "benchmark" / "v1"
PAGE = REPO / "docs" / "leaderboard.md"
COMMAND = generate_command("docs/results/benchmark/v1", "docs/leaderboard.md", "docs/results/img")


def _a_folder() -> Path:
    """The committed folder with the fewest episodes' bytes (quickest to re-derive)."""
    return min((p.parent for p in ROOT.glob("*/*/scores.json")), key=lambda p: p.stat().st_size)


def _copy(folder: Path, tmp_path: Path) -> Path:
    copy = tmp_path / "v1" / folder.parent.name / folder.name
    shutil.copytree(folder, copy)
    return copy


def test_the_page_is_the_generators_output_of_the_committed_folders():
    rows = read_rows(ROOT, verify=False)
    assert rows, f"no results under {ROOT}"
    assert PAGE.read_text(encoding="utf-8") == markdown(
        rows, "results/benchmark/v1", "results/img", COMMAND
    ), f"docs/leaderboard.md is stale: run {COMMAND}"


def test_each_system_is_ranked_by_its_iqm_and_every_row_is_official():
    rows = read_rows(ROOT, verify=False)
    page = PAGE.read_text(encoding="utf-8")
    for env in {row.env for row in rows}:
        section = page.split(f"## {env.split('/')[-1]}\n")[1].split("\n## ")[0]
        iqms = [
            float(line.split(" | ")[-2].split(" [")[0])
            for line in section.splitlines()
            if line.startswith("| ") and line[2].isdigit()
        ]
        assert len(iqms) == sum(row.env == env for row in rows)
        assert iqms == sorted(iqms, reverse=True)
    for path in ROOT.glob("*/*/scores.json"):
        assert json.loads(path.read_text())["official"] is True, path


def test_the_committed_folders_hold_only_the_published_files():
    for folder in {p.parent for p in ROOT.glob("*/*/scores.json")}:
        assert sorted(p.name for p in folder.iterdir()) == sorted(PUBLISHED), folder


def test_a_changed_episode_value_is_refused_and_the_untouched_copy_accepted(tmp_path):
    copy = _copy(_a_folder(), tmp_path)
    (row,) = read_rows(tmp_path / "v1", verify=True)
    assert row.folder == copy
    lines = list(csv.reader((copy / "episodes.csv").open()))
    lines[5][-1] = str(float(lines[5][-1]) + 0.25)
    with (copy / "episodes.csv").open("w", newline="") as f:
        csv.writer(f, lineterminator="\n").writerows(lines)
    with pytest.raises(FolderCheckError):
        read_rows(tmp_path / "v1", verify=True)
    assert main(["generate", str(tmp_path / "v1"), "--out", str(tmp_path / "page.md"),
                 "--figures", str(tmp_path / "img")]) == 1  # fmt: skip
    assert not (tmp_path / "page.md").exists()


def test_an_unofficial_folder_is_refused(tmp_path):
    copy = _copy(_a_folder(), tmp_path)
    doc = json.loads((copy / "scores.json").read_text())
    doc["official"] = False
    (copy / "scores.json").write_text(json.dumps(doc))
    with pytest.raises(FolderCheckError, match="unofficial"):
        read_rows(tmp_path / "v1", verify=False)


def test_publish_copies_the_published_files_only(tmp_path):
    run = tmp_path / "run"
    shutil.copytree(_a_folder(), run)
    (run / "levels").mkdir()
    (run / "timing.json").write_text("{}")
    dest = publish(run, tmp_path / "root", same_packages=False)
    assert dest.relative_to(tmp_path / "root").parts == _a_folder().parts[-2:]
    assert sorted(p.name for p in dest.iterdir()) == sorted(PUBLISHED)
    for name in PUBLISHED:
        assert (dest / name).read_bytes() == (run / name).read_bytes()


def test_a_missing_root_is_one_line_and_exit_code_2(tmp_path, capsys):
    assert main(["generate", str(tmp_path / "nope"), "--out", "x.md", "--figures", "img"]) == 2
    err = capsys.readouterr().err.strip()
    assert "is not a folder" in err and "\n" not in err


def test_generate_without_rliable_is_one_line_before_anything_is_written(
    tmp_path, capsys, monkeypatch
):
    copy = _copy(_a_folder(), tmp_path)
    monkeypatch.setitem(sys.modules, "rliable", None)  # import rliable now raises
    out, figures = tmp_path / "page.md", tmp_path / "img"
    assert (
        main(["generate", str(copy.parents[1]), "--out", str(out), "--figures", str(figures)]) == 2
    )
    err = capsys.readouterr().err.strip()
    assert "pip install 'observer-gym[rl]'" in err and "\n" not in err
    assert not out.exists() and not figures.exists()


@pytest.mark.slow
def test_every_committed_folder_re_derives():
    assert len(read_rows(ROOT, verify=True)) == len(list(ROOT.glob("*/*/scores.json")))
