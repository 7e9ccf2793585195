"""Checkpoints of a training run that survive an interruption at any instant.

A checkpoint is ``checkpoints/model_<N>.zip`` (the SB3 model, N its timestep count), with
``vecnormalize_<N>.npz`` (plain arrays: :mod:`~observer_gym.train.rl.normalizer_file`)
if the run normalises and ``replay_buffer_<N>.pkl`` for the
off-policy algorithms. Each file is written to a temporary name and renamed into place;
then ``checkpoint_<N>.json`` records the set's files and their sha256, and
``checkpoints/latest.json`` (the same record) names the newest complete set, replaced
last. Ctrl-C and SIGTERM wait until the set is saved
(:func:`~observer_gym.train.core.signals.signals_deferred`); a run killed while saving
(SIGKILL, power) leaves the previous set named and intact; the temp files such a kill
leaves (``.model_<N>.zip.tmp-<PID>``, ...) are removed when the run is resumed
(:func:`observer_gym.train.reports.outputs.remove_stale_temps`). A resumed run starts from the
newest set whose files match their hashes
(:func:`~observer_gym.train.rl.run_dir.intact_checkpoint`). Only the newest ``keep`` sets
stay on disk.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from observer_gym.extras import require_rl
from observer_gym.train.core.atomic_write import replace_atomically
from observer_gym.train.core.signals import signals_deferred
from observer_gym.train.reports.outputs import write_json_atomic
from observer_gym.train.rl.callbacks import EveryStepsCallback
from observer_gym.train.rl.normalizer_file import save_normalizer
from observer_gym.train.rl.run_dir import (  # noqa: F401  (latest_checkpoint: read here too)
    LATEST,
    MANIFEST,
    file_sha256,
    latest_checkpoint,
)

# without the [rl] extra, the error names its install line
require_rl("training an agent (observer_gym.train.rl)")
from stable_baselines3.common.base_class import BaseAlgorithm  # noqa: E402
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm  # noqa: E402


def save_checkpoint(
    model: BaseAlgorithm, directory: Path, save_replay_buffer: bool, keep: int = 2
) -> dict[str, Any]:
    """Save ``model`` (and its VecNormalize statistics and replay buffer) as the newest
    checkpoint in ``directory``; returns the entry written to ``latest.json``."""
    directory.mkdir(parents=True, exist_ok=True)
    steps = int(model.num_timesteps)
    entry: dict[str, Any] = {"timesteps": steps, "model": f"model_{steps}.zip"}
    with signals_deferred():  # a signal waits for the whole set and latest.json
        replace_atomically(directory / entry["model"], model.save)
        vec_normalize = model.get_vec_normalize_env()
        if vec_normalize is not None:
            entry["vecnormalize"] = f"vecnormalize_{steps}.npz"
            save_normalizer(vec_normalize, directory / entry["vecnormalize"])
        if save_replay_buffer and isinstance(model, OffPolicyAlgorithm):
            entry["replay_buffer"] = f"replay_buffer_{steps}.pkl"
            replace_atomically(directory / entry["replay_buffer"], model.save_replay_buffer)
        names = [v for k, v in entry.items() if k != "timesteps"]
        entry["sha256"] = {name: file_sha256(directory / name) for name in names}
        write_json_atomic(directory / MANIFEST.format(steps), entry)
        write_json_atomic(directory / LATEST, entry)
        _prune(directory, keep)
    return entry


def _prune(directory: Path, keep: int) -> None:
    steps = sorted(
        {int(p.stem.split("_")[-1]) for p in directory.glob("model_*.zip")}, reverse=True
    )
    for old in steps[keep:]:
        for name in (
            MANIFEST.format(old),  # first: a set without its manifest is never picked
            f"model_{old}.zip",
            f"vecnormalize_{old}.npz",
            f"vecnormalize_{old}.pkl",  # written by earlier versions
            f"replay_buffer_{old}.pkl",
        ):
            (directory / name).unlink(missing_ok=True)


class CheckpointCallback(EveryStepsCallback):
    """Saves a checkpoint (:func:`save_checkpoint`) every ``every_steps`` env steps."""

    def __init__(self, directory: Path, every_steps: int, save_replay_buffer: bool) -> None:
        super().__init__(every_steps)
        self.directory, self.save_replay_buffer = Path(directory), save_replay_buffer

    def act(self) -> None:
        save_checkpoint(self.model, self.directory, self.save_replay_buffer)
