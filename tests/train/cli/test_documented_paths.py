"""What a new user meets on the documented paths (issue 42): one signature family for the
experiment functions' episodes, shipped agents by name wherever an agent is taken, and an
outside entry refused on a system it does not fit, in one line naming it."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from observer_gym.envs import system_for_id
from observer_gym.train.cli import main
from observer_gym.train.core import entries
from observer_gym.train.core.observer_env import resolve_observer
from observer_gym.train.experiments import api, catalogue
from observer_gym.train.experiments.episode import check_entries
from observer_gym.train.experiments.request import resolve_controller
from observer_gym.train.rl.run_dir import agent_folder
from observer_gym.train.rl.shipped import shipped_path

ROOT = Path(__file__).resolve().parents[3]
EXAMPLE = ROOT / "examples" / "your_method"
BALL_PD = "mylab.control:make_controller"


# --- episodes= and seeds= ------------------------------------------------------------------
@pytest.mark.parametrize(
    ("episodes", "seed", "seeds", "expected"),
    [
        (None, None, None, list(range(10))),
        (3, None, None, [0, 1, 2]),
        (2, 5, None, [5, 6]),
        (None, None, [4, 9, 2], [4, 9, 2]),
        (3, 4, range(4, 7), [4, 5, 6]),  # both given, agreeing
    ],
)
def test_episodes_seed_and_seeds_name_the_same_episodes(episodes, seed, seeds, expected):
    assert api.episode_seeds(episodes, seed, seeds) == expected


@pytest.mark.parametrize(
    ("episodes", "seed", "seeds", "consecutive", "message"),
    [
        (2, None, [0, 1, 2], False, r"episodes=2 and seeds=\[0, 1, 2\] disagree"),
        (None, 1, [0, 1], False, r"seed=1 and seeds=\[0, 1\] disagree"),
        (None, None, [], False, "at least one seed"),
        (None, None, [0, -1], False, "integers >= 0"),
        (None, None, "0-3", False, "a sequence of integers"),
        (0, None, None, False, "episodes must be an integer >= 1"),
        (None, None, [3, 7], True, "consecutive seeds"),
    ],
)
def test_inconsistent_or_bad_episodes_are_a_value_error(
    episodes, seed, seeds, consecutive, message
):
    with pytest.raises(ValueError, match=message):
        api.episode_seeds(episodes, seed, seeds, consecutive=consecutive)


class _Called(Exception):
    """Raised by a stand-in for the experiment, carrying the arguments it got."""


def _capture(monkeypatch, module: str, function: str) -> None:
    import importlib

    # the modules that import these by name are imported before any is replaced
    for imported in ("compare", "run", "sweep", "evaluate"):
        importlib.import_module(f"observer_gym.train.experiments.{imported}")

    def stand_in(*args, **kwargs):
        raise _Called(kwargs)

    monkeypatch.setattr(importlib.import_module(module), function, stand_in)


def test_compare_takes_episodes_and_run_sweep_evaluate_take_seeds(monkeypatch, tmp_path):
    _capture(monkeypatch, "observer_gym.train.experiments.compare", "run_comparison")
    _capture(monkeypatch, "observer_gym.train.experiments.run", "run_experiment")
    _capture(monkeypatch, "observer_gym.train.experiments.sweep", "run_sweep")
    _capture(monkeypatch, "observer_gym.train.experiments.evaluate", "evaluate_agent")
    with pytest.raises(_Called) as called:
        api.compare("BallTable-v0", "kf-measurements", "lqr", episodes=2, seed=3, out_dir=tmp_path)
    assert called.value.args[0]["seeds"] == [3, 4]
    with pytest.raises(_Called) as called:
        api.run("BallTable-v0", "kf-measurements", "lqr", seeds=range(3, 5), out_dir=tmp_path)
    assert (called.value.args[0]["episodes"], called.value.args[0]["seed"]) == (2, 3)
    with pytest.raises(_Called) as called:
        api.sweep(
            "BallTable-v0", {"latency_s": [0.0]}, "kf-measurements", "lqr", seeds=[1, 2, 3],
            out_dir=tmp_path,
        )  # fmt: skip
    assert (called.value.args[0]["episodes"], called.value.args[0]["seed"]) == (3, 1)
    with pytest.raises(_Called) as called:
        api.evaluate("ppo:ball_table-estimate", seeds=[7], out_dir=tmp_path)
    assert called.value.args[0]["seed"] == 7
    with pytest.raises(ValueError, match="disagree"):
        api.compare("BallTable-v0", "kf-measurements", "lqr", episodes=2, seeds=[0, 1, 2])


# --- shipped agents by name ----------------------------------------------------------------
def test_a_shipped_agent_is_taken_by_name_wherever_an_agent_is_taken(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # no folder of that name here
    folder = shipped_path("ball_table-estimate")
    assert agent_folder("ppo:ball_table-estimate") == folder
    assert agent_folder("ball_table-estimate") == folder
    assert agent_folder(folder) == folder
    with pytest.raises(ValueError, match=r"nor a shipped agent \(.*ball_table-estimate"):
        agent_folder("ball_table-nothing")
    with pytest.raises(ValueError, match="holds a ppo agent, not sac"):
        agent_folder("sac:ball_table-estimate")


def test_evaluate_takes_a_shipped_agent_by_name(tmp_path, capsys):
    out = tmp_path / "out"
    code = main(
        ["evaluate", "--model", "ball_table-estimate", "--episodes", "1", "--steps", "5",
         "--out", str(out), "--no-progress"]
    )  # fmt: skip
    printed = capsys.readouterr()
    assert code == 0, printed.err
    assert printed.out.startswith("observer-gym evaluate: observer_gym/BallTable-v0")
    assert (out / "results.json").is_file()
    assert main(["evaluate", "--model", "ball_table-nothing", "--out", str(out)]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "nor a shipped agent" in line


# --- an outside entry on a system it does not fit ------------------------------------------
@pytest.fixture
def example(monkeypatch):
    """The example package (examples/your_method) on sys.path, its systems declaration
    removed or kept by the test."""
    monkeypatch.syspath_prepend(str(EXAMPLE))
    import mylab.control

    return mylab.control


def _check_entries(env_id: str, observer: str, controller: str) -> None:
    """check_entries on the pair's entries resolved by name."""
    system = system_for_id(env_id)
    check_entries(
        system, resolve_observer(system, observer), resolve_controller(system, controller)
    )


def test_a_declared_entry_is_refused_elsewhere_in_one_line(example):
    with pytest.raises(ValueError) as refused:
        _check_entries("observer_gym/BallCatcher-v1", "kf-measurements", BALL_PD)
    assert str(refused.value) == (
        f"controller {BALL_PD!r} does not fit BallCatcher-v1: it declares it is made for "
        "BallTable-v0 (its factory's systems)"
    )
    _check_entries(
        "observer_gym/BallTable-v0", "kf-measurements", BALL_PD
    )  # where it fits, it runs


def test_an_undeclared_entry_that_does_not_fit_is_named_with_the_cause(example, monkeypatch):
    monkeypatch.delattr(example.make_controller, "systems")
    with pytest.raises(ValueError) as refused:
        _check_entries("observer_gym/BallCatcher-v1", "kf-measurements", BALL_PD)
    message = str(refused.value)
    assert "\n" not in message
    assert message.startswith(f"controller {BALL_PD!r}: predict() raised ValueError: operands")
    assert message.endswith("(on BallCatcher-v1, tried before any episode)")


def test_list_shows_the_systems_an_entry_fits(example, monkeypatch):
    plugin = entries.find_plugin("controller", BALL_PD)
    assert catalogue.entry_systems(plugin) == ("observer_gym/BallTable-v0",)  # declared
    monkeypatch.delattr(example.make_controller, "systems")
    fits = catalogue.entry_systems(plugin)  # by trial (the tests' toy system may fit too)
    assert "observer_gym/BallTable-v0" in fits
    assert not {"observer_gym/BallCatcher-v1", "observer_gym/TargetFollower-v0"} & set(fits)


def test_a_bad_declaration_is_a_value_error():
    def factory(env):
        return None

    factory.systems = 3  # type: ignore[attr-defined]
    with pytest.raises(ValueError, match="expected env ids"):
        entries.declared_systems(factory)


# --- the README's and docs' commands ------------------------------------------------------
def _commands(path: Path, command: str) -> list[list[str]]:
    """Every ``observer-gym COMMAND --...`` of a Markdown page (in code blocks and inline;
    not the lines it prints), its lines joined, as words."""
    text = path.read_text().replace("\\\n", " ")
    start = f"observer-gym {command} -"
    found = [line for line in text.splitlines() if line.strip().startswith(start)]
    found += re.findall(rf"`({start}[^`]*)`", text.replace("\n", " "))
    return [shlex.split(" ".join(line.split("#")[0].split())) for line in found]


def test_every_readme_run_command_names_its_observer_and_controller():
    commands = _commands(ROOT / "README.md", "run")
    assert len(commands) >= 2
    for words in commands:
        assert "--observer" in words and "--controller" in words, " ".join(words)


def test_the_sweep_examples_write_different_folders():
    """The README's sweep and docs/sweep.md's (command and Python) would refuse each other's
    folder ('holds a sweep with other arguments')."""
    outs = [
        words[words.index("--out") + 1]
        for page in (ROOT / "README.md", ROOT / "docs" / "sweep.md")
        for words in _commands(page, "sweep")
        if "--out" in words
    ]
    outs += re.findall(r'out_dir="([^"]+)"', (ROOT / "docs" / "sweep.md").read_text())
    assert len(outs) >= 3
    assert len(set(outs)) == len(outs), outs


def test_the_readme_names_each_modes_space():
    """The Dict spaces, which Gymnasium's image and normalisation wrappers refuse, are said."""
    import gymnasium as gym

    readme = (ROOT / "README.md").read_text()
    rows = {line.split("|")[1].strip(" `"): line for line in readme.splitlines()
            if line.startswith("| `observer_gym/")}  # fmt: skip
    for env_id, row in rows.items():
        for mode in ("rgb", "measurements"):
            env = gym.make(env_id, obs_mode=mode)
            try:
                is_dict = isinstance(env.observation_space, gym.spaces.Dict)
            finally:
                env.close()
            said = re.search(rf"`{mode}`: (\*\*Dict\*\*|Box)", row)
            assert said is not None, (env_id, mode)
            assert (said.group(1) == "**Dict**") == is_dict, (env_id, mode)


# --- docs/your_method.md: its command and the published copy --------------------------------
def test_your_methods_command_writes_outside_the_tracked_docs_and_the_page_quotes_its_table():
    """The page's sweep writes an untracked folder (runs/, ignored), not the published
    copy under docs/results/; every row the page quotes is a row of that copy's table
    (short names for the example's entries)."""
    page = (ROOT / "docs" / "your_method.md").read_text(encoding="utf-8")
    command = page.split("observer-gym sweep", 1)[1].split("```", 1)[0]
    out = shlex.split(command.replace("\\\n", " "))
    out_dir = out[out.index("--out") + 1]
    assert not out_dir.startswith("docs/"), out_dir
    assert "runs/" in (ROOT / ".gitignore").read_text(encoding="utf-8").split()
    published = (ROOT / "docs" / "results" / "your_method" / "table.md").read_text()
    names = {
        "alpha-beta": "mylab.filters:make_observer-measurements",
        "PD": "mylab.control:make_controller",
    }
    table = {
        tuple(cell.strip() for cell in line.strip("|").split("|"))
        for line in published.splitlines()
        if re.match(r"\| \d", line)
    }
    quoted = [line for line in page.splitlines() if re.match(r"\| 0\.\d \| ", line)]
    assert len(quoted) >= 12
    for line in quoted:
        cells = [cell.strip() for cell in line.strip("|").split("|")]
        cells = [names.get(cell, cell) for cell in cells]
        assert tuple(cells) in table, line
