"""Putting a trained agent into the package (:mod:`observer_gym.train.rl.shipped`) and
checking that a shipped agent still acts as it did when it was shipped.

:func:`ship_agent` copies what loading needs from a finished run folder (``config.json``,
``model.zip``, ``vecnormalize.npz``; a ``state.json`` cut down to the status and the
timestep count) into ``train/rl/agents/<name>/``, the config's recorded ``--out`` made
relative (``runs/<its last folder>``: the trainer's machine's path means nothing
elsewhere), records their sha256 in ``final.json``
(checked whenever the agent is loaded), writes the README it is given and
``fingerprint.json``: an observation (the first one of the env the agent reads, reset
with :data:`FINGERPRINT_SEED`) and the agent's deterministic action for it. A test loads
every shipped agent and compares its action on that observation with the fingerprint
(:func:`fingerprint_difference`), so a change in stable-baselines3, PyTorch or our loading
code that changes what a shipped agent does is caught.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from observer_gym.envs import system_for_id
from observer_gym.envs.json_file import read_json
from observer_gym.train.core.observer_env import make_env, resolve_observer
from observer_gym.train.reports.outputs import to_jsonable, write_json_atomic
from observer_gym.train.rl.agent import Agent
from observer_gym.train.rl.normalizer_file import record_final_files
from observer_gym.train.rl.run_dir import (
    FINAL_MODEL,
    FINAL_VECNORMALIZE,
    STATE_FILE,
    model_files,
    read_config,
    read_state,
    write_config,
)
from observer_gym.train.rl.shipped import FINGERPRINT_FILE, README_FILE, SHIPPED_DIR

FINGERPRINT_SEED = 0


class Fingerprint(NamedTuple):
    """An observation and the action a shipped agent gave for it."""

    observation: Any  # an array, or a dict of arrays for a Dict observation
    action: np.ndarray  # in the env's units


def fingerprint_observation(agent: Agent) -> Any:
    """The first observation of the env ``agent`` reads (its training observer and env
    options, the agent's wrappers), reset with :data:`FINGERPRINT_SEED`."""
    config = agent.config
    system = system_for_id(config["env_id"])
    observer = resolve_observer(system, config["observer"])
    env = agent.wrap_env(make_env(system, observer, config["env_kwargs"]))
    try:
        observation, _ = env.reset(seed=FINGERPRINT_SEED)
    finally:
        env.close()
    return observation


def take_fingerprint(agent: Agent) -> Fingerprint:
    """``agent``'s deterministic action on :func:`fingerprint_observation`."""
    observation = fingerprint_observation(agent)
    action, _ = agent.predict(observation, deterministic=True)
    return Fingerprint(observation, np.asarray(action))


def read_fingerprint(folder: str | Path) -> Fingerprint:
    """The ``fingerprint.json`` of the shipped agent in ``folder``."""
    data = read_json(Path(folder) / FINGERPRINT_FILE)
    observation = data["observation"]
    dtype = data.get("observation_dtype", "float32")
    if isinstance(observation, dict):
        observation = {k: np.asarray(v, dtype=dtype) for k, v in observation.items()}
    else:
        observation = np.asarray(observation, dtype=dtype)
    return Fingerprint(observation, np.asarray(data["action"], dtype=np.float64))


def fingerprint_difference(folder: str | Path) -> float:
    """The largest absolute difference between the action the agent in ``folder`` gives
    now on its fingerprint's observation and the fingerprint's action."""
    fingerprint = read_fingerprint(folder)
    action, _ = Agent.load(folder).predict(fingerprint.observation, deterministic=True)
    return float(np.max(np.abs(np.asarray(action, dtype=np.float64) - fingerprint.action)))


def _dtype(observation: Any) -> str:
    first = next(iter(observation.values())) if isinstance(observation, dict) else observation
    return str(np.asarray(first).dtype)


def shipped_config(config: dict[str, Any]) -> dict[str, Any]:
    """``config`` with its recorded ``--out`` (``cli_args["out"]``) as ``runs/<its last
    folder>``, the form the shipped READMEs' commands use."""
    cli_args = config.get("cli_args")
    if not isinstance(cli_args, dict) or not cli_args.get("out"):
        return config
    out = Path(str(cli_args["out"]))
    return {**config, "cli_args": {**cli_args, "out": (Path("runs") / out.name).as_posix()}}


def ship_agent(run_dir: str | Path, name: str, readme: str, folder: Path = SHIPPED_DIR) -> Path:
    """Copy the finished run in ``run_dir`` into ``folder/name/`` (replacing what is
    there) with ``readme`` as its README.md and a new fingerprint; returns the folder.

    Raises:
        ValueError: the run has not finished (no model.zip), its files are not those it
            recorded, or ``name`` is no plain folder name.
    """
    run_dir = Path(run_dir)
    if not name or Path(name).name != name or name.startswith("."):
        raise ValueError(f"name must be a plain folder name (ball_table-estimate), got {name!r}")
    if not (run_dir / FINAL_MODEL).is_file():
        raise ValueError(f"{run_dir} has no {FINAL_MODEL}: only a finished run can be shipped")
    config = read_config(run_dir)  # refuses a changed config before anything is copied
    model_files(run_dir)  # its files as recorded, no pickled statistics
    state = read_state(run_dir) or {}
    target = folder / name
    if target.exists():
        shutil.rmtree(target)
    target.mkdir(parents=True)
    for file in (FINAL_MODEL, FINAL_VECNORMALIZE):
        if (run_dir / file).is_file():
            shutil.copyfile(run_dir / file, target / file)
    write_config(target, shipped_config(config))
    record_final_files(target)
    write_json_atomic(
        target / STATE_FILE,
        {"status": state.get("status"), "timesteps": state.get("timesteps")},
    )
    (target / README_FILE).write_text(readme, encoding="utf-8")
    fingerprint = take_fingerprint(Agent.load(target))
    write_json_atomic(
        target / FINGERPRINT_FILE,
        {
            "seed": FINGERPRINT_SEED,
            "observation": to_jsonable(fingerprint.observation),
            "observation_dtype": _dtype(fingerprint.observation),
            "action": to_jsonable(fingerprint.action.astype(np.float64)),
        },
    )
    return target
