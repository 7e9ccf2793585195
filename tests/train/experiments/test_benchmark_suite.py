"""The benchmark suite's data files: every shipped file validates, its seeds are fixed,
and a bad file is refused naming the file, the key and what is allowed."""

from __future__ import annotations

import copy
import json

import pytest

from observer_gym.envs import SYSTEMS, system_for_id
from observer_gym.train.experiments.benchmark.suite import (
    DOC_SEEDS,
    load_suite,
    parse_suite,
    suite_path,
    suite_versions,
)

PACKAGE_ENVS = ("BallTable-v0", "BallCatcher-v1", "TargetFollower-v0")
LEVELS = ("ideal", "lab", "field")


@pytest.mark.parametrize("env_id", PACKAGE_ENVS)
def test_shipped_suite_files_validate(env_id):
    suite = load_suite(env_id, "v1")
    assert suite.version == "v1" and suite.env_id == system_for_id(env_id).env_id
    assert [level.name for level in suite.levels] == list(LEVELS)
    # ideal is the env's defaults; the others switch options on
    assert suite.level("ideal").env_options == {}
    config_class = suite.system.env_class().config_class
    defaults = config_class.from_kwargs()
    for name in ("lab", "field"):
        options = suite.level(name).env_options
        config = config_class.from_kwargs(**options)
        assert any(getattr(config, key) != getattr(defaults, key) for key in options)
    for refs in suite.references.values():
        assert refs.episodes == suite.episodes
        assert refs.oracle != refs.floor(suite.metric.better)[1]


def test_v1_is_the_only_version_and_covers_the_package_systems():
    assert "v1" in suite_versions()
    for system in SYSTEMS[:3]:
        assert suite_path("v1", system).is_file()


def test_seeds_are_fixed_unique_and_not_the_docs():
    seen: set[int] = set()
    for env_id in PACKAGE_ENVS:
        suite = load_suite(env_id)
        for level in suite.levels:
            seeds = level.seeds(suite.episodes)
            assert seeds == list(range(level.seed_start, level.seed_start + suite.episodes))
            assert seeds == load_suite(env_id).level(level.name).seeds(suite.episodes)
            assert not set(seeds) & set(DOC_SEEDS)
            assert not set(seeds) & seen  # every level of every system has its own seeds
            seen |= set(seeds)


def _data(env_id="BallTable-v0"):
    system = system_for_id(env_id)
    return system, json.loads(suite_path("v1", system).read_text())


def _refused(data, system, match, version="v1"):
    with pytest.raises(ValueError, match=match):
        parse_suite(data, system, version, "the/file.json")


def test_an_unknown_option_is_refused_naming_the_key():
    system, data = _data()
    data["levels"]["lab"]["env_options"]["latency_ms"] = 3
    _refused(data, system, r"the/file\.json: levels\.lab\.env_options: .*latency_ms")


def test_an_option_out_of_range_is_refused_naming_the_range():
    system, data = _data()
    data["levels"]["field"]["env_options"]["frame_drop_prob"] = 1.5
    _refused(data, system, r"levels\.field\.env_options: frame_drop_prob=1\.5 .*\[0\.0, 1\.0\]")


def test_a_wrong_version_or_env_is_refused():
    system, data = _data()
    _refused(data, system, r"suite: is 'v1'; this file is suite 'v2'", version="v2")
    other = copy.deepcopy(data)
    other["env"] = "BallCatcher-v1"
    _refused(other, system, r"env: is 'BallCatcher-v1'; this file is 'BallTable-v0'")


def test_overlapping_or_doc_seeds_are_refused():
    system, data = _data()
    data["levels"]["lab"]["seed_start"] = data["levels"]["ideal"]["seed_start"] + 1
    _refused(data, system, r"levels\.lab\.seed_start: its seeds .* overlap level 'ideal'")
    system, data = _data()
    data["levels"]["lab"]["seed_start"] = 42
    _refused(data, system, r"levels\.lab\.seed_start: is 42; allowed: an integer >= 100")
    system, data = _data()
    data["levels"]["lab"]["seed_start"] = 1.5e6
    _refused(data, system, r"levels\.lab\.seed_start: must be an integer")


def test_bad_metric_controller_keys_and_references_are_refused():
    system, data = _data()
    data["metric"]["name"] = "accuracy"
    _refused(data, system, r"metric\.name: is 'accuracy'; allowed: mean_distance_m")
    system, data = _data()
    data["metric"]["better"] = "higher"
    _refused(data, system, r"metric\.better: is 'higher'; the task's is 'lower'")
    system, data = _data()
    data["controller"] = "intercept"
    _refused(data, system, r"controller: is 'intercept'; allowed: lqr, mpc, pid")
    system, data = _data()
    data["extra"] = 1
    _refused(data, system, r"top level: unknown key 'extra'; allowed: suite, env")
    system, data = _data()
    data["levels"]["ideal"]["references"]["episodes"] = 3
    _refused(data, system, r"levels\.ideal\.references\.episodes: is 3")
    system, data = _data()
    del data["levels"]["ideal"]["references"]["oracle"]
    _refused(data, system, r"levels\.ideal\.references\.oracle: missing")
    system, data = _data()
    refs = data["levels"]["ideal"]["references"]
    refs["raw"] = refs["idle"] = refs["oracle"]
    _refused(data, system, r"levels\.ideal\.references: the oracle's .* equals the floor's")


def test_a_file_is_named_when_it_is_not_json(tmp_path):
    path = tmp_path / "ball_table.json"
    path.write_text("{not json")
    with pytest.raises(ValueError, match=r"ball_table\.json: cannot be read as JSON"):
        load_suite("BallTable-v0", "v1", path=path)
    with pytest.raises(ValueError, match=r"unknown suite version 'v9'; allowed: v1"):
        load_suite("BallTable-v0", "v9")
