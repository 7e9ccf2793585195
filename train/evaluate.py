"""``observer-gym evaluate``: a trained agent's closed-loop episodes, scored exactly as
``observer-gym run`` scores a baseline controller (same metrics, same results.json)."""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from observer_gym.train.outputs import OutputFolderWarning
from observer_gym.train.run import run_experiment
from observer_gym.train.run_dir import killed_text, model_files, read_config, read_state


def evaluate_agent(
    run_dir: str | Path,
    episodes: int,
    out_dir: str | Path,
    seed: int = 0,
    observer: str | None = None,
    steps: int | None = None,
    workers: int = 1,
    progress: bool = True,
    cli_args: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Run ``episodes`` episodes (seeds ``seed``, ``seed + 1``, ...) of the agent trained
    in ``run_dir`` on its env with its training env options, reading ``observer``'s output
    (default: the observer it was trained on; an agent trained on the state or an
    estimate also runs on any other observer of the state layout). Writes and returns
    ``run_experiment``'s results; the agent is the final model, or the latest checkpoint
    of a run that has not finished. A run that was killed
    (:func:`~observer_gym.train.run_dir.read_state`) is reported with an
    :class:`~observer_gym.train.outputs.OutputFolderWarning` naming the checkpoint used."""
    config = read_config(run_dir)
    _, _, trained_steps = model_files(run_dir)  # a clear error now if there is nothing to load
    state = read_state(run_dir)
    if state is not None and state["status"] == "killed":
        warnings.warn(
            f"{killed_text(run_dir, state)}; evaluating its latest checkpoint "
            f"({trained_steps} steps)",
            OutputFolderWarning,
            stacklevel=2,
        )
    return run_experiment(
        env_id=config["env_id"],
        observer=observer or config["observer"],
        controller=f"{config['algo']}:{run_dir}",
        episodes=episodes,
        seed=seed,
        out_dir=out_dir,
        steps=steps,
        workers=workers,
        progress=progress,
        env_kwargs=config["env_kwargs"],
        cli_args=cli_args,
    )
