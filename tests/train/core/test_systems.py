"""One record per system: every layer has its part of every system of SYSTEMS, the
command line offers what the layers hold, and a subclass of an env finds its system."""

from __future__ import annotations

import argparse
import importlib

import gymnasium as gym
import pytest

from observer_gym.controllers import ControllerDesign, controllers_for, make_controller
from observer_gym.envs import SYSTEMS, system_for_id, system_named, system_of
from observer_gym.estimation import VisionObserver, observers_of
from observer_gym.estimation.observer import env_options_of
from observer_gym.train import cli
from observer_gym.train.cli.args import controller_name
from observer_gym.train.core.checks import check_observer
from observer_gym.train.core.systems import (
    controller_choices,
    observer_choices,
    system_entries,
)
from observer_gym.train.core.tasks import task_of

LAYERS = ("envs", "estimation", "controllers", "task")


@pytest.mark.parametrize("system", SYSTEMS, ids=lambda s: s.name)
def test_every_layer_holds_its_part_of_the_system(system):
    for layer in LAYERS:
        importlib.import_module(system.module(layer))
    spec = gym.spec(system.env_id)
    assert spec.entry_point == system.entry_point
    assert spec.max_episode_steps == system.max_episode_steps
    assert system.env_class().__module__.startswith(system.module("envs"))

    estimation = importlib.import_module(system.module("estimation"))
    assert estimation.OBSERVERS and all(map(callable, estimation.OBSERVERS.values()))
    controllers = importlib.import_module(system.module("controllers")).CONTROLLERS
    assert controllers and all(isinstance(c, ControllerDesign) for c in controllers.values())
    assert controllers_for(system.env_id) is controllers

    task = task_of(system)
    assert task.__name__ == system.module("task")
    assert task.OBSERVERS["oracle"] == ("state", {})
    assert set(task.ESTIMATE_OBSERVERS.values()) <= set(task.OBSERVERS)
    for name in ("SUMMARY_ROWS", "COMPARE_METRICS", "CONFIG"):
        assert getattr(task, name) is not None
    for name in ("episode_metrics", "summarize", "plot"):
        assert callable(getattr(task, name))


@pytest.mark.parametrize("system", SYSTEMS, ids=lambda s: s.name)
def test_every_observer_of_the_task_builds_its_pipeline(system):
    for observer, (obs_mode, options) in task_of(system).OBSERVERS.items():
        if options is None or observer == "oracle":
            continue
        needed = env_options_of(system, options.get("observer"))  # e.g. the hole's pixels
        env = VisionObserver(gym.make(system.env_id, obs_mode=obs_mode, **needed), **options)
        env.close()


def test_the_look_ups_find_each_system():
    for system in SYSTEMS:
        assert system_named(system.name) is system
        assert system_for_id(system.env_id) is system_for_id(system.short_id) is system
    with pytest.raises(ValueError, match="unknown env 'BallPool-v0'; allowed: BallTable-v0"):
        system_for_id("BallPool-v0")
    with pytest.raises(ValueError, match="unknown system 'ball_pool'; known: ball_table"):
        system_named("ball_pool")
    cartpole = gym.make("CartPole-v1")
    with pytest.raises(ValueError, match=r"CartPoleEnv is not an env of a known system.*BallTable"):
        system_of(cartpole)
    cartpole.close()


def test_a_retired_id_names_its_replacement():
    """BallCatcher moved to v1 (docs/envs.md): v0 is not registered; Gymnasium's make
    names v1 and our look-up says why and which release reproduces v0."""
    for env_id in ("BallCatcher-v0", "observer_gym/BallCatcher-v0"):
        with pytest.raises(ValueError, match=r"no longer registered: BallCatcher-v1 .*v0\.1\.0"):
            system_for_id(env_id)
    assert "observer_gym/BallCatcher-v0" not in gym.registry
    with pytest.raises(gym.error.DeprecatedEnv, match="Please use `observer_gym/BallCatcher-v1`"):
        gym.make("observer_gym/BallCatcher-v0")


@pytest.mark.parametrize("system", SYSTEMS, ids=lambda s: s.name)
def test_a_subclass_of_an_env_finds_its_system_observers_and_controllers(system):
    cls = system.env_class()
    subclass = type(f"My{cls.__name__}", (cls,), {})
    observers = importlib.import_module(system.module("estimation")).OBSERVERS
    needed = {k: v for name in observers for k, v in env_options_of(system, name).items()}
    env = subclass(obs_mode="measurements", **needed)  # what every observer needs
    try:
        assert system_of(env) is system
        assert system_of(gym.wrappers.RecordEpisodeStatistics(env)) is system
        assert observers_of(env) is observers
        for name in observers:
            wrapped = VisionObserver(env, observer=name)
            assert wrapped.observation_space == env.state_space
        with pytest.raises(ValueError, match=f"allowed: {', '.join(observers)}"):
            VisionObserver(env, observer="no-such-observer")
        for name in controllers_for(system.env_id):
            make_controller(name, env)
        for other in SYSTEMS:
            if other is system:
                continue
            for name in controllers_for(other.env_id):
                if name in controllers_for(system.env_id):
                    continue  # the name is this system's too ("lqr"): its own design
                fits = ", ".join(controllers_for(system.env_id))
                with pytest.raises(ValueError, match=f"{system.short_id} takes: {fits}"):
                    make_controller(name, env)
    finally:
        env.close()


def test_the_command_line_offers_what_the_layers_hold(monkeypatch):
    entries = system_entries()
    observers = {o for entry in entries for o in entry.observers}
    controllers = {c for entry in entries for c in entry.controllers}
    assert set(observer_choices()) == observers and set(controller_choices()) == controllers
    parser = cli.build_parser()
    for entry in entries:  # the command takes every observer of a system for it
        for name in entry.observers:
            assert check_observer(entry.system.short_id, name) == entry.env_id
    for name in controllers:
        assert controller_name(name) == name
    with pytest.raises(argparse.ArgumentTypeError):
        controller_name("lqg")
    monkeypatch.setenv("COLUMNS", "100000")  # --help on one line per option
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    helps = {command: sub.choices[command].format_help() for command in ("run", "compare")}
    for entry in entries:  # --help lists them, read from the layers when it is shown
        for field in ("controllers", "observers"):
            listed = f"{entry.system.short_id}: {', '.join(getattr(entry, field))}"
            for command, text in helps.items():
                assert listed in text, (command, listed)


def test_run_says_which_controllers_fit_the_env(capsys):
    argv = ["run", "--env", "BallCatcher-v1", "--observer", "oracle", "--controller", "lqr"]
    assert cli.main(argv) == 2
    assert "BallCatcher-v1 takes: intercept" in capsys.readouterr().err
