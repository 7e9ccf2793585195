"""Folders and files made to hurt: links where a command writes, JSON with a key twice or
nested past Python's parser, a results file linked to ``/dev/zero``, a training run
without its recorded hashes, a benchmark level file holding NaN, a full disk while the
leaderboard is published or generated, and names that would inject Markdown. Each is
refused in one line (or run again), and no file outside the folder is written."""

from __future__ import annotations

import json
import os
import shutil
import warnings
from pathlib import Path

import pytest
from markdown_it import MarkdownIt  # a dependency of rich, which observer-gym requires
from run_folders import STEPS, file_size_limit, snapshot

from observer_gym.envs.json_file import JSONFileError, parse_json, read_json
from observer_gym.train.cli import main
from observer_gym.train.experiments.benchmark import leaderboard
from observer_gym.train.experiments.benchmark.check import FolderCheckError, check_folder
from observer_gym.train.experiments.benchmark.run import check_benchmark, run_benchmark
from observer_gym.train.reports.folder_lock import LOCK_FILE, folder_lock
from observer_gym.train.reports.outputs import OutputFolderError
from observer_gym.train.rl import run_dir
from observer_gym.train.rl.shipped import shipped_path

REPO = Path(__file__).resolve().parents[3]
ROOT = REPO / "docs" / "results" / "benchmark" / "v1"


# --- the JSON reader ---------------------------------------------------------------------
def test_the_reader_refuses_a_key_twice_nan_and_deep_nesting(tmp_path):
    with pytest.raises(JSONFileError, match="the key 'aggregate' appears twice"):
        parse_json('{"aggregate": 1, "x": {}, "aggregate": 2}', "scores.json")
    with pytest.raises(JSONFileError, match="NaN is not JSON"):
        parse_json('{"values": [NaN]}', "lab.json")
    assert parse_json('{"values": [NaN]}', "lab.json", allow_nan=True)["values"][0] != 0
    with pytest.raises(JSONFileError, match="nested deeper"):
        parse_json("[" * 100_000 + "]" * 100_000, "deep.json")  # past Python's parser
    with pytest.raises(JSONFileError, match="nested deeper than 64 levels"):
        parse_json("[" * 65 + "]" * 65, "deep.json")
    assert parse_json("[" * 64 + "]" * 64, "ok.json") is not None
    path = tmp_path / "big.json"
    path.write_text("[" + "0," * 100 + "0]")
    with pytest.raises(JSONFileError, match=f"{path} is larger than 100 bytes"):
        read_json(path, max_bytes=100)


@pytest.mark.timeout(30)
def test_the_reader_refuses_devices_and_fifos_at_once(tmp_path):
    link = tmp_path / "scores.json"
    link.symlink_to("/dev/zero")
    with pytest.raises(JSONFileError, match="not a regular file"):
        read_json(link)
    fifo = tmp_path / "fifo.json"
    os.mkfifo(fifo)
    with pytest.raises(JSONFileError, match="not a regular file"):
        read_json(fifo)  # no writer: a plain open would wait forever


# --- links where a command writes ----------------------------------------------------------
def test_a_linked_lock_file_is_refused_and_its_target_kept(tmp_path, capsys):
    victim = tmp_path / "precious.txt"
    victim.write_text("keep me\n")
    out = tmp_path / "out"
    out.mkdir()
    (out / LOCK_FILE).symlink_to(victim)
    with pytest.raises(OSError, match="is a symbolic link, which is never followed"):
        with folder_lock(out, "run"):
            pass
    argv = ["run", "--env", "BallTable-v0", "--observer", "oracle", "--controller", "lqr"]
    assert main([*argv, "--episodes", "1", "--steps", "3", "--no-progress", "--out", str(out)]) == 1
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith("observer-gym run: error: could not lock") and "symbolic link" in line
    assert victim.read_text() == "keep me\n"
    assert (out / LOCK_FILE).is_symlink()  # left for its owner to remove


@pytest.fixture
def run(tiny_run, tmp_path) -> Path:
    return Path(shutil.copytree(tiny_run, tmp_path / "run"))


RESUME = ["train", "--no-progress", "--timesteps", str(3 * STEPS), "--resume"]


@pytest.mark.slow  # resumes a PPO training: 3.6 s (load ~2)
def test_resume_replaces_linked_eval_and_monitor_files_never_writing_through(run, tmp_path):
    outside = tmp_path / "outside"
    outside.mkdir()
    links = {"eval.csv": outside / "eval.csv", "monitor/0.monitor.csv": outside / "mon.csv"}
    for name, target in links.items():
        shutil.copyfile(run / name, target)
        (run / name).unlink()
        (run / name).symlink_to(target)
    before = snapshot(outside)
    assert main([*RESUME, str(run)]) == 0
    assert snapshot(outside) == before  # nothing written through the links
    for name in links:
        assert not (run / name).is_symlink() and (run / name).is_file(), name
    rows = (run / "eval.csv").read_text().splitlines()
    # the header, the evaluation at 128 steps (read through the link) and at 192
    assert rows[0].startswith("timesteps,") and len(rows) == 3
    assert rows[1] == before["eval.csv"].decode().splitlines()[1]
    assert rows[2].startswith(f"{3 * STEPS},")


def test_resume_with_a_malformed_eval_csv_is_one_line_naming_it(run, capsys):
    (run / "eval.csv").write_text("timesteps,wall_time_s\n1,abc\n")
    before = snapshot(run)
    assert main([*RESUME, str(run)]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith(f"observer-gym train: error: {run / 'eval.csv'} is not a training")
    assert "header" in line
    assert snapshot(run) == before  # refused before anything was trained or written


def test_resume_with_a_garbage_state_json_warns(run, capsys):
    (run / "state.json").write_text("\x00garbage{")
    assert main([*RESUME, str(run)]) == 0
    (line,) = capsys.readouterr().err.splitlines()
    assert line == (
        f"observer-gym train: warning: {run / 'state.json'} is not readable as a run's state; "
        f"resuming from the checkpoint at {2 * STEPS} steps and writing a new one"
    )
    assert run_dir.read_state(run)["status"] == "finished"


def test_a_config_without_its_hash_is_refused(run, capsys):
    path = run / "config.json"
    config = json.loads(path.read_text())
    del config["config_sha256"]
    path.write_text(json.dumps(config))
    with pytest.raises(ValueError, match=r"records no config_sha256 .* --trust-pickle"):
        run_dir.read_config(run)
    assert main([*RESUME, str(run)]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith(f"observer-gym train: error: {path} records no config_sha256")


def test_a_config_with_a_key_twice_is_refused(run):
    path = run / "config.json"
    text = path.read_text()
    path.write_text(text.replace('{\n  "env_id"', '{\n  "algo": "sac",\n  "env_id"', 1))
    with pytest.raises(ValueError, match="the key 'algo' appears twice"):
        run_dir.read_config(run)


def test_a_run_without_final_json_is_refused_before_anything_is_unpickled(
    tmp_path, capsys, monkeypatch
):
    """model.zip is partly unpickled by stable-baselines3: without final.json nothing
    vouches for it, so the folder is refused before SB3 is asked to load it."""
    folder = tmp_path / "agent"
    shutil.copytree(shipped_path("ball_table-estimate"), folder)
    (folder / "final.json").unlink()
    import stable_baselines3

    loaded = []
    monkeypatch.setattr(stable_baselines3.PPO, "load", lambda *a, **k: loaded.append(a))
    out = tmp_path / "out"
    argv = ["evaluate", "--model", str(folder), "--episodes", "1", "--steps", "2"]
    assert main([*argv, "--no-progress", "--out", str(out)]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith("observer-gym evaluate: error: ")
    assert "no final.json" in line and "untrusted" in line and "--trust-pickle" in line
    assert loaded == []
    # whoever trusts it records it; then it loads
    from observer_gym.train.rl.normalizer_file import main as convert

    assert convert(["--trust-pickle", str(folder)]) == 0
    assert (folder / "final.json").is_file()
    run_dir.model_files(folder)  # checks out now


def test_checkpoint_records_without_hashes_are_untrusted(run, capsys):
    """A checkpoint record whose sha256 was removed vouches for nothing: the checkpoint
    is passed over like a damaged one (none left: one line), nothing is loaded; vouched
    for with the conversion command, it resumes."""
    records = [*sorted((run / "checkpoints").glob("checkpoint_*.json"))]
    records.append(run / "checkpoints" / "latest.json")
    for record in records:
        entry = json.loads(record.read_text())
        del entry["sha256"]
        record.write_text(json.dumps(entry))
    with pytest.raises(ValueError, match=r"no intact checkpoint to resume from: .*untrusted"):
        run_dir.check_resumable(run)
    assert main([*RESUME, str(run)]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert "has no sha256 recorded in its checkpoint record: untrusted" in line
    from observer_gym.train.rl.normalizer_file import main as convert

    assert convert(["--trust-pickle", str(run)]) == 0
    run_dir.check_resumable(run)
    assert "sha256" in json.loads(records[-1].read_text())


def test_a_shipped_config_carries_its_hash():
    from observer_gym.train.rl.shipped import shipped_names

    for name in shipped_names():
        assert "config_sha256" in read_json(shipped_path(name) / "config.json"), name
        run_dir.read_config(shipped_path(name))


def test_seed_0_and_seed_00_are_refused_naming_both(tmp_path, capsys):
    folder = tmp_path / "seeds"
    for name in ("seed_0", "seed_00"):
        shutil.copytree(shipped_path("ball_table-estimate"), folder / name)
    with pytest.raises(OutputFolderError, match=r"seed_0 and .*seed_00 are both seed 0"):
        run_dir.seed_run_dirs(folder)
    argv = ["evaluate", "--model", str(folder), "--episodes", "1", "--steps", "2"]
    assert main([*argv, "--no-progress", "--out", str(tmp_path / "out")]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert "seed_00 are both seed 0" in line


# --- other commands' folders -----------------------------------------------------------------
def _training_folder(out: Path) -> dict[str, bytes]:
    out.mkdir()
    run_dir.write_config(out, {"algo": "ppo"})
    return snapshot(out)


def test_sweep_and_demo_refuse_a_training_runs_folder(tmp_path, capsys):
    out = tmp_path / "run"
    before = _training_folder(out)
    sweep = ["sweep", "--env", "BallTable-v0", "--steps", "3", "--vary", "latency_s=0"]
    sweep += ["--observers", "oracle", "--controllers", "lqr", "--episodes", "1"]
    for argv in ([*sweep, "--out", str(out)], ["demo", "--seconds", "0.1", "--out", str(out)]):
        assert main([*argv, "--no-progress"]) == 2, argv[0]
        (line,) = capsys.readouterr().err.splitlines()
        assert line.endswith(f"{out} holds 'observer-gym train' results; use another output folder")
        assert snapshot(out) == before
    from observer_gym.train.experiments.demo import run_demo

    with pytest.raises(OutputFolderError, match="holds 'observer-gym train' results"):
        run_demo(out, seconds=0.1, progress=False)


# --- learned weights ---------------------------------------------------------------------------
def test_malformed_learned_weights_are_a_value_error_naming_the_file(tmp_path):
    import torch

    from observer_gym.estimation.learned.network import (
        GaussianMLP,
        file_sha256,
        load_network,
        save_network,
    )

    path = tmp_path / "net.pt"
    save_network(GaussianMLP(2, 1, 4), path, {})
    torch.save({"architecture": {"n_in": 3, "n_out": 1, "hidden": 4}, "state_dict": {}}, path)
    report = json.loads(path.with_suffix(".json").read_text())
    report["sha256"] = file_sha256(path)  # a report that vouches for the wrong file
    path.with_suffix(".json").write_text(json.dumps(report))
    with pytest.raises(ValueError, match=f"learned observer weights {path} cannot be loaded"):
        load_network(path)
    path.write_bytes(b"PK\x03\x04 not a zip")
    report["sha256"] = file_sha256(path)
    path.with_suffix(".json").write_text(json.dumps(report))
    with pytest.raises(ValueError, match=f"learned observer weights {path} cannot be loaded"):
        load_network(path)
    path.with_suffix(".json").write_text("[1, 2]")
    with pytest.raises(ValueError, match="is not the report of learned observer weights"):
        load_network(path)


# --- a received benchmark folder ----------------------------------------------------------------
def _a_folder() -> Path:
    """The committed folder with the fewest episodes' bytes (quickest to re-derive)."""
    return min((p.parent for p in ROOT.glob("*/*/scores.json")), key=lambda p: p.stat().st_size)


def _copy(tmp_path: Path, folder: Path | None = None) -> Path:
    folder = folder or _a_folder()
    copy = tmp_path / "v1" / folder.parent.name / folder.name
    shutil.copytree(folder, copy)
    return copy


def test_check_refuses_a_forged_first_key(tmp_path, capsys):
    """A forged first "aggregate" that a reader keeping the first key would show, the
    real one after it: refused, as a key twice."""
    copy = _copy(tmp_path)
    check_folder(copy, same_packages=False)
    text = (copy / "scores.json").read_text()
    forged = '{\n  "aggregate": {"iqm": 1.0, "low": 1.0, "high": 1.0},' + text[1:]
    (copy / "scores.json").write_text(forged)
    with pytest.raises(FolderCheckError, match="the key 'aggregate' appears twice"):
        check_folder(copy, same_packages=False)
    assert main(["benchmark", "--check", str(copy)]) == 1
    (line,) = capsys.readouterr().err.splitlines()
    assert "appears twice" in line


def test_check_of_deep_json_is_one_line(tmp_path, capsys):
    copy = _copy(tmp_path)
    (copy / "scores.json").write_text("[" * 200_000 + "]" * 200_000)
    assert main(["benchmark", "--check", str(copy)]) == 1
    (line,) = capsys.readouterr().err.splitlines()
    assert "nested deeper" in line


@pytest.mark.timeout(60)
def test_check_of_episodes_linked_to_dev_zero_is_one_line(tmp_path, capsys):
    copy = _copy(tmp_path)
    (copy / "episodes.csv").unlink()
    (copy / "episodes.csv").symlink_to("/dev/zero")
    assert main(["benchmark", "--check", str(copy)]) == 1
    (line,) = capsys.readouterr().err.splitlines()
    assert "episodes.csv is not a regular file" in line


@pytest.mark.slow  # runs a benchmark level twice: 2.8 s (load ~2)
def test_a_nan_in_a_level_file_runs_the_level_again(tmp_path):
    request = check_benchmark("BallCatcher-v1", "kf-measurements", "intercept", episodes=2)
    out = tmp_path / "bench"
    run_benchmark(request, out, progress=False)
    before = (out / "scores.json").read_text()
    level = json.loads((out / "levels" / "lab.json").read_text())
    level["values"][0] = float("nan")
    (out / "levels" / "lab.json").write_text(json.dumps(level))  # Python writes NaN
    with pytest.warns(UserWarning, match=r"level 'lab' .* runs again: .*NaN is not JSON"):
        result = run_benchmark(request, out, progress=False)
    assert result.reused == ("ideal", "field")
    assert (out / "scores.json").read_text() == before


# --- the leaderboard ------------------------------------------------------------------------------
def test_publish_on_a_full_disk_keeps_the_good_copy(tmp_path, capsys):
    run = tmp_path / "run"
    shutil.copytree(_a_folder(), run)
    root = tmp_path / "root"
    dest = leaderboard.publish(run, root, same_packages=False)
    good = snapshot(dest)
    assert len(good["episodes.csv"]) > 2_000
    with file_size_limit(2_000):
        with pytest.raises(OSError, match=r"could not write .*File too large"):
            leaderboard.publish(run, root, same_packages=False)
    assert snapshot(dest) == good  # not cut short in place
    assert [p.name for p in dest.iterdir() if p.name.startswith(".")] == []
    assert len(leaderboard.read_rows(root, verify=False)) == 1  # the root still generates


def test_generate_on_a_full_disk_is_one_line(tmp_path, capsys):
    pytest.importorskip("rliable")
    _copy(tmp_path)
    out, figures = tmp_path / "page.md", tmp_path / "img"
    argv = ["generate", str(tmp_path / "v1"), "--out", str(out), "--figures", str(figures)]
    with file_size_limit(1_000):
        code = leaderboard.main(argv)
    assert code == 1
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith(f"{leaderboard.PROG}: error: could not write ")
    assert line.endswith("File too large")
    assert not out.exists()


@pytest.mark.parametrize("into", ["x" * 300, "root/\0name"], ids=["300 characters", "NUL"])
def test_publish_into_a_bad_name_is_one_line_and_exit_code_2(tmp_path, capsys, into):
    run = tmp_path / "run"
    shutil.copytree(_a_folder(), run)
    assert leaderboard.main(["publish", str(run), "--into", str(tmp_path / into)]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith(f"{leaderboard.PROG}: error: ")
    assert "NUL" in line or "longer than a file name can be (255 bytes)" in line


HOSTILE = "kf`|<img src=x onerror=alert(1)>\n# Owned [x](javascript:alert(1))"


@pytest.mark.parametrize("name", [HOSTILE, "x" * 300, "a\0b", "", "-rf"])
def test_a_folder_naming_no_entry_is_refused_on_publish_and_generate(tmp_path, capsys, name):
    copy = _copy(tmp_path)
    doc = json.loads((copy / "scores.json").read_text())
    doc["controller"] = name
    (copy / "scores.json").write_text(json.dumps(doc))
    with pytest.raises(
        leaderboard.EntryNameError, match=r"controller .* is no entry name: letters"
    ):
        leaderboard.read_rows(tmp_path / "v1", verify=False)
    assert leaderboard.main(["publish", str(copy), "--into", str(tmp_path / "root")]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert "is no entry name" in line
    assert not (tmp_path / "root").exists()


def _html(page: str) -> str:
    return MarkdownIt("commonmark").enable("table").render(page)


def test_the_page_escapes_what_it_writes():
    """Rows whose names and version hold Markdown and HTML (as a folder read without the
    name check would give): the page shows them as text, with no heading, image, link or
    raw HTML of theirs, and one table row each."""
    rows = leaderboard.read_rows(ROOT, verify=False)
    hostile = [
        rows[0]._replace(
            observer=HOSTILE,
            controller="``a`` | b",
            command=f"observer-gym benchmark --observer '{HOSTILE}'",
            version="<script>alert(1)</script>",
        ),
        *rows[1:],
    ]
    plain_page = _html(leaderboard.markdown(rows, "r", "img", "cmd"))
    page = leaderboard.markdown(hostile, "r", "img", "cmd")
    html = _html(page)
    assert "<img src=x" not in html and "<script>" not in html
    assert 'href="javascript' not in html
    assert "<h1>Owned" not in html and html.count("<h1>") == 1
    assert html.count("<tr>") == plain_page.count("<tr>")  # no row split or added
    assert html.count("<li>") == plain_page.count("<li>")
    # and the text is all there, as text
    assert "&lt;img src=x onerror=alert(1)&gt;\\n# Owned" in html
    assert "&lt;script&gt;alert(1)&lt;/script&gt;" in html


def test_the_same_run_in_two_folders_is_refused(tmp_path):
    copy = _copy(tmp_path)
    shutil.copytree(copy, copy.parent / "copied-again")
    with pytest.raises(FolderCheckError, match="whose published folder is"):
        leaderboard.read_rows(tmp_path / "v1", verify=False)


def test_the_committed_leaderboard_reads_and_renders_unchanged():
    """Every committed folder passes the name checks (the page test in
    test_benchmark_leaderboard.py shows the page is unchanged)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rows = leaderboard.read_rows(ROOT, verify=False)
    assert len(rows) == len(list(ROOT.glob("*/*/scores.json")))


@pytest.mark.parametrize(
    "text",
    [
        "timesteps,return_mean\n64,1.0,7\n",
        "steps,mean\n64,1.0\n",
        "timesteps,return_mean\n64,nan\n",
    ],
    ids=["wide-row", "other-columns", "nan"],
)
def test_the_multi_seed_aggregate_names_a_malformed_eval_csv(text, tmp_path):
    """The curves across seeds read each seed's eval.csv: a malformed one is a ValueError
    naming it (a resume checks the file itself, the test above)."""
    from observer_gym.train.reports.aggregate import read_eval_curve

    (tmp_path / "eval.csv").write_text(text)
    with pytest.raises(ValueError, match=rf"^{tmp_path / 'eval.csv'} is not an evaluation curve"):
        read_eval_curve(tmp_path, seed=0)
    (tmp_path / "eval.csv").write_text("timesteps,return_mean\n64,1.0\n128,2.5\n64,1.5\n")
    curve = read_eval_curve(tmp_path, seed=3)
    assert curve is not None and curve.timesteps == (64, 128) and curve.return_mean == (1.5, 2.5)
