"""The folder of an ``observer-gym train`` run as the other commands read it: its
``config.json``, its ``state.json`` (how the run stands, a killed one told apart), its
final model or latest checkpoint, and the ``ALGO:DIR`` names of trained agents; and the
folder of a multi-seed run (``train --seeds``), which holds one such run per seed in
``seed_<s>/``.

Reading these imports neither PyTorch nor stable-baselines3, so ``observer-gym run``,
``evaluate`` and ``compare`` check a trained agent before any heavy import;
:mod:`observer_gym.train.rl.agent` loads it.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from pathlib import Path
from typing import Any, NamedTuple

from observer_gym.envs.json_file import read_json
from observer_gym.extras import require_rl
from observer_gym.train.core.algorithms import ALGOS
from observer_gym.train.core.checks import UNFILTERED_OBSERVERS
from observer_gym.train.reports.folder_lock import check_not_busy
from observer_gym.train.reports.outputs import (
    OutputFolderError,
    write_json_atomic,
    writer_alive,
)
from observer_gym.train.rl.normalizer_file import (
    CONFIG_SHA256,
    FINAL_STATS,
    VOUCH_COMMAND,
    check_final_files,
    config_sha256,
    pickled_stats_message,
)
from observer_gym.train.rl.shipped import shipped_path

CONFIG_FILE = "config.json"
STATE_FILE = "state.json"
FINAL_MODEL = "model.zip"
FINAL_VECNORMALIZE = FINAL_STATS  # plain arrays (normalizer_file); never a pickle
CHECKPOINTS = "checkpoints"
LATEST = "latest.json"  # in checkpoints/: the newest complete checkpoint
MANIFEST = "checkpoint_{}.json"  # in checkpoints/: each set's files and their sha256
SEED_PREFIX = "seed_"  # a multi-seed run's folder holds seed_<s>/ per seed
SEEDS_FILE = "seeds.json"  # and, written by train --seeds, what it trains


def parse_agent_spec(name: str) -> tuple[str, Path] | None:
    """``("ppo", Path("runs/x"))`` for ``"ppo:runs/x"``; None for a name without ``ALGO:``
    (a baseline controller's name). ``ALGO:NAME`` where no folder ``NAME`` exists but an
    agent of that name is shipped (:mod:`observer_gym.train.rl.shipped`) gives the shipped
    agent's folder."""
    algo, sep, run_dir = name.partition(":")
    if not sep or algo not in ALGOS:
        return None
    if not run_dir:
        raise ValueError(f"agent {name!r} names no folder; expected {algo}:DIR")
    shipped = None if Path(run_dir).exists() else shipped_path(run_dir)
    return algo, shipped if shipped is not None else Path(run_dir)


def agent_folder(model: str | Path) -> Path:
    """The folder of the agent ``model`` names, wherever an agent is taken alone
    (``evaluate``): a folder (a training run or a multi-seed run), ``ALGO:DIR``, or a
    shipped agent as ``ALGO:NAME`` or ``NAME`` (``ppo:ball_table-estimate``) when no
    folder of that name exists.

    Raises:
        ValueError: no folder and no shipped agent of that name (the message lists the
            shipped ones), or ``ALGO:`` naming a run trained with another algorithm.
    """
    text = str(model)
    if Path(text).exists():
        return Path(text)
    spec = parse_agent_spec(text)
    if spec is not None and spec[1].exists():
        algo, folder = spec
        if folder.is_dir() and not is_multi_seed(folder):
            read_config(folder, algo)  # the algorithm it names is the run's
        return folder
    shipped = shipped_path(text)
    if shipped is not None:
        return shipped
    from observer_gym.train.rl.shipped import shipped_names

    names = ", ".join(shipped_names())
    raise ValueError(
        f"{text} is not an observer-gym training run (no such folder) nor a shipped agent "
        f"({names}; also as ALGO:NAME, e.g. ppo:ball_table-estimate); make one with "
        "'observer-gym train'"
    )


def seed_run_dirs(folder: str | Path) -> dict[int, Path]:
    """The runs of a multi-seed folder: seed -> ``folder/seed_<seed>``, for every such
    subfolder, by seed; empty for any other folder.

    Raises:
        OutputFolderError: (a ValueError) two subfolders name the same seed (``seed_0``
            and ``seed_00``), naming both.
    """
    folder = Path(folder)
    runs: dict[int, Path] = {}
    for path in sorted(folder.glob(f"{SEED_PREFIX}*")) if folder.is_dir() else []:
        number = path.name.removeprefix(SEED_PREFIX)
        if path.is_dir() and number.isascii() and number.isdigit():
            seed = int(number)
            if seed in runs:
                raise OutputFolderError(
                    f"{runs[seed]} and {path} are both seed {seed}: one multi-seed folder "
                    f"holds one run per seed ({SEED_PREFIX}{seed}); keep one of them"
                )
            runs[seed] = path
    return dict(sorted(runs.items()))


def is_multi_seed(folder: str | Path) -> bool:
    """Whether ``folder`` is a multi-seed run: no run of its own (no config.json) but
    ``seed_<s>/`` subfolders."""
    return not (Path(folder) / CONFIG_FILE).exists() and bool(seed_run_dirs(folder))


def expand_agent(name: str) -> list[str]:
    """``name`` as the controllers it stands for: ``ALGO:DIR`` of a multi-seed folder is
    one agent per seed (``ALGO:DIR/seed_<s>``, by seed); any other name is itself."""
    spec = parse_agent_spec(name)
    if spec is None or not is_multi_seed(spec[1]):
        return [name]
    return [f"{spec[0]}:{path}" for path in seed_run_dirs(spec[1]).values()]


def check_new_run_folder(run_dir: str | Path) -> None:
    """:class:`~observer_gym.train.reports.outputs.OutputFolderError` (a ValueError) if
    ``run_dir`` already holds a training run (its config.json). ``train`` checks it before
    anything runs and again once it holds the folder's lock, before it writes there."""
    check_not_busy(run_dir)  # a run training there now: FolderBusyError, exit code 75
    if (Path(run_dir) / CONFIG_FILE).exists():
        raise OutputFolderError(
            f"{run_dir} already holds a training run; continue it with --resume"
        )


def check_new_seeds_folder(out_dir: str | Path) -> None:
    """:class:`~observer_gym.train.reports.outputs.OutputFolderError` (a ValueError) if
    ``out_dir`` already holds a run, single or multi-seed (``train --seeds`` checks it
    before anything runs and again under the folder's lock)."""
    check_new_run_folder(out_dir)
    if (Path(out_dir) / SEEDS_FILE).exists() or seed_run_dirs(out_dir):
        raise OutputFolderError(
            f"{out_dir} already holds a multi-seed training run; continue it with --resume"
        )


def write_config(run_dir: str | Path, config: Mapping[str, Any]) -> None:
    """Write ``config`` as ``run_dir``'s config.json, atomically, with its sha256
    (:func:`config_sha256`) recorded in it, which :func:`read_config` checks."""
    config = {k: v for k, v in config.items() if k != CONFIG_SHA256}
    write_json_atomic(Path(run_dir) / CONFIG_FILE, {**config, CONFIG_SHA256: config_sha256(config)})


def read_config(run_dir: str | Path, algo: str | None = None) -> dict[str, Any]:
    """The resolved config.json of the training run in ``run_dir`` (without its recorded
    sha256).

    Raises:
        ValueError: no training run there (no such folder, no config.json or one that is
            not JSON), a config.json changed since the run wrote it (its content does not
            match the sha256 recorded in it) or recording none, one naming no known
            algorithm, or one
            trained with another algorithm than ``algo``.
    """
    path = Path(run_dir) / CONFIG_FILE
    if not Path(run_dir).is_dir():
        raise ValueError(
            f"{run_dir} is not an observer-gym training run (no such folder); "
            "make one with 'observer-gym train'"
        )
    if not path.is_file():
        seeds = list(seed_run_dirs(run_dir))
        if seeds:
            raise ValueError(
                f"{run_dir} holds a multi-seed run (seeds {', '.join(map(str, seeds))}), not "
                "one agent: 'evaluate' and 'compare' take it whole; name one seed's run as "
                f"{Path(run_dir) / f'{SEED_PREFIX}{seeds[0]}'}"
            )
        raise ValueError(
            f"{run_dir} is not an observer-gym training run (no {CONFIG_FILE}); "
            "make one with 'observer-gym train'"
        )
    try:
        config = read_json(path)
    except OSError as exc:
        raise ValueError(f"{path} cannot be read: {exc.strerror or exc}") from None
    if not isinstance(config, dict):
        raise ValueError(f"{path} is not a run's configuration (a JSON object)")
    recorded = config.pop(CONFIG_SHA256, None)
    if recorded is None:
        raise ValueError(
            f"{path} records no {CONFIG_SHA256} (every run writes one; a config.json without "
            f"it was edited or comes from a version before 0.2): refused; if the folder "
            f"comes from a source you trust, vouch for it with {VOUCH_COMMAND} {run_dir}"
        )
    if recorded != config_sha256(config):
        raise ValueError(
            f"{path} was changed after the run wrote it (its content does not match the "
            f"{CONFIG_SHA256} recorded in it): the run's model was trained with the recorded "
            "settings; restore the file, or train a new run with the settings you want"
        )
    if config.get("algo") not in ALGOS:
        raise ValueError(f"{path} names algo {config.get('algo')!r}; allowed: {', '.join(ALGOS)}")
    if algo is not None and config["algo"] != algo:
        raise ValueError(f"{run_dir} holds a {config['algo']} agent, not {algo}")
    return config


class TrainedWith(NamedTuple):
    """What a trained agent's folder says it needs to act as trained."""

    observer: str  # the observer it was trained on ("pixels" for an rgb agent)
    env_options: dict[str, Any]  # its env_kwargs (image size, reward shaping)


def trained_with(run_dir: str | Path, algo: str | None = None) -> TrainedWith:
    """The observer and env options the agent in ``run_dir`` was trained with, from its
    config.json (:func:`read_config`, whose ValueErrors it raises)."""
    config = read_config(run_dir, algo)
    return TrainedWith(str(config["observer"]), dict(config.get("env_kwargs") or {}))


def read_state(run_dir: str | Path) -> dict[str, Any] | None:
    """The ``state.json`` of the training run in ``run_dir`` (None if it has none, or one
    that is not JSON), with ``status`` "killed" for a run that says "running" but whose
    writer is gone.

    A run records its writer (``pid``, ``host``, ``pid_start``: see
    :func:`observer_gym.train.reports.outputs.writer_identity`) when it starts and rewrites the
    file when it ends (finished, interrupted by Ctrl-C or SIGTERM). One killed with
    SIGKILL (or a power cut) cannot, so it stays "running"; it is reported "killed" when
    its PID is no longer a running process of the recorded start time on this host
    (:func:`observer_gym.train.reports.outputs.writer_alive`), or when it recorded no writer
    (written before writers were recorded: then nothing can still be writing it). A run
    on another host is taken as still running.
    """
    path = Path(run_dir) / STATE_FILE
    try:
        state = read_json(path)
    except (OSError, ValueError):
        return None
    if not isinstance(state, dict):
        return None
    if state.get("status") == "running" and not writer_alive(state.get("writer") or {}):
        state["status"] = "killed"
    return state


def _writer_text(state: dict[str, Any]) -> str:
    writer = state.get("writer") or {}
    if "pid" not in writer:
        return "its writer (not recorded)"
    return f"pid {writer['pid']} on {writer.get('host', '?')}"


def killed_text(run_dir: str | Path, state: dict[str, Any]) -> str:
    """One sentence on the killed run in ``run_dir`` (``state`` from :func:`read_state`)."""
    return (
        f"the training run in {run_dir} was killed: its state.json says running but "
        f"{_writer_text(state)} is gone"
    )


def check_resumable(run_dir: str | Path) -> dict[str, Any] | None:
    """Check that the training run in ``run_dir`` can be resumed: it has a config, an
    intact checkpoint (:func:`intact_checkpoint`) and is not running (:func:`read_state`).
    Returns its state (None if it has no state.json).

    Raises:
        ValueError: no training run there, no intact checkpoint (naming what is wrong with
            each), or a run still writing it.
    """
    check_not_busy(run_dir)  # a run training there now: FolderBusyError, exit code 75
    read_config(run_dir)
    checkpoint, problems = intact_checkpoint(Path(run_dir) / CHECKPOINTS)
    if checkpoint is None:
        if problems:
            raise ValueError(
                f"{run_dir} has no intact checkpoint to resume from: {'; '.join(problems)}"
            )
        raise ValueError(f"{run_dir} has no checkpoint to resume from")
    if str(checkpoint.get("vecnormalize", "")).endswith(LEGACY_STATS_SUFFIX):
        raise ValueError(pickled_stats_message(checkpoint["vecnormalize"]))
    state = read_state(run_dir)
    if state is not None and state.get("status") == "running":
        raise ValueError(
            f"the training run in {run_dir} is still running ({_writer_text(state)}); "
            "stop it before resuming"
        )
    return state


def _entry_paths(directory: Path, entry: Mapping[str, Any]) -> dict[str, Path | int]:
    return {
        k: (v if k == "timesteps" else directory / v) for k, v in entry.items() if k != "sha256"
    }


def latest_checkpoint(directory: Path) -> dict[str, Any] | None:
    """The newest complete checkpoint in ``directory`` as ``latest.json`` names it (its
    files as paths and its ``timesteps``), or None if none was saved.

    Raises:
        ValueError: latest.json is not the JSON a checkpoint writes.
    """
    path = Path(directory) / LATEST
    if not path.exists():
        return None
    entry = _read_entry(path)
    if entry is None:
        raise ValueError(f"{path} is damaged: not the JSON object of a checkpoint")
    return _entry_paths(Path(directory), entry)


CHECKPOINT_FILES = {"model": "model_{}.zip", "vecnormalize": "vecnormalize_{}.npz",
                    "replay_buffer": "replay_buffer_{}.pkl"}  # fmt: skip
LEGACY_STATS_SUFFIX = ".pkl"  # vecnormalize_<N>.pkl of earlier versions: named, never loaded


def _read_entry(path: Path) -> dict[str, Any] | None:
    """A checkpoint's entry (latest.json, a manifest), or None if it is not one: its
    ``timesteps`` N, its files as :data:`CHECKPOINT_FILES` names them for N (a model at
    least) and, if recorded, their ``sha256``."""
    try:
        entry = read_json(path)
    except (OSError, ValueError):
        return None
    if not isinstance(entry, dict) or "model" not in entry:
        return None
    steps = entry.get("timesteps")
    if not isinstance(steps, int) or isinstance(steps, bool) or steps < 0:
        return None
    files = {k: v for k, v in entry.items() if k not in ("timesteps", "sha256")}
    legacy = {"vecnormalize": f"vecnormalize_{steps}{LEGACY_STATS_SUFFIX}"}
    allowed = {k: (name.format(steps), legacy.get(k)) for k, name in CHECKPOINT_FILES.items()}
    if any(v not in allowed.get(k, ()) for k, v in files.items()):
        return None
    if "sha256" in entry and not isinstance(entry["sha256"], dict):
        return None
    return entry


def file_sha256(path: Path) -> str:
    """The sha256 of the file ``path``, read in 1 MiB blocks."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(1 << 20):
            digest.update(block)
    return digest.hexdigest()


def _problem(directory: Path, entry: Mapping[str, Any]) -> str | None:
    """What is wrong with the checkpoint ``entry``: a file missing, one that is not as
    saved (its sha256 differs from the one recorded then), or no sha256 recorded (the
    record is untrusted: nothing is loaded from it); None if nothing."""
    names = [v for k, v in entry.items() if k not in ("timesteps", "sha256")]
    for name in names:
        if not (directory / name).is_file():
            return f"{directory / name} is missing"
    recorded = entry.get("sha256")
    if not isinstance(recorded, dict):  # removed, or written before 0.2: nothing vouches
        return (
            f"{directory / entry['model']} has no sha256 recorded in its checkpoint record: "
            "untrusted, not loaded (loading a model unpickles part of it); if the folder "
            f"comes from a source you trust, record it with {VOUCH_COMMAND} DIR"
        )
    for name in names:
        if recorded.get(name) != file_sha256(directory / name):
            return f"{directory / name} is damaged (not the file that was saved)"
    return None


def intact_checkpoint(directory: Path) -> tuple[dict[str, Any] | None, list[str]]:
    """The newest checkpoint in ``directory`` whose files are all there and as saved
    (:func:`save_checkpoint <observer_gym.train.rl.checkpoints.save_checkpoint>` records
    each set's files and their sha256 in ``checkpoint_<N>.json``, and ``latest.json``
    names the newest: sets after it are not considered, unless latest.json is damaged),
    as :func:`latest_checkpoint` gives it, or None; and one sentence on each newer
    checkpoint passed over (a file missing or damaged, a damaged latest.json)."""
    directory = Path(directory)
    entries: dict[int, dict[str, Any]] = {}
    problems = []
    newest = None  # latest.json's count: no set after it counts (it never completed)
    paths = sorted(directory.glob(MANIFEST.format("*"))) if directory.is_dir() else []
    for path in [directory / LATEST, *paths]:
        if not path.exists():
            continue
        entry = _read_entry(path)
        if entry is None:
            problems.append(f"{path} is damaged")
            continue
        if path.name == LATEST:
            newest = entry["timesteps"]
        if newest is None or entry["timesteps"] <= newest:
            entries.setdefault(entry["timesteps"], entry)
    for steps in sorted(entries, reverse=True):
        problem = _problem(directory, entries[steps])
        if problem is None:
            return _entry_paths(directory, entries[steps]), problems
        problems.append(problem)
    return None, problems


def model_files(run_dir: str | Path) -> tuple[Path, Path | None, int | None]:
    """(model, VecNormalize statistics or None, timesteps or None): the final model of a
    finished run, else its latest checkpoint. The timesteps of a final model without
    checkpoints (a shipped agent) are its state.json's.

    Raises:
        ValueError: neither a final model nor a checkpoint; files that are not those the
            run recorded (a final model and statistics against final.json, a checkpoint's
            against its sha256); statistics saved as a pickle by an earlier version
            (:func:`~observer_gym.train.rl.normalizer_file.pickled_stats_message`).
    """
    run_dir = Path(run_dir)
    checkpoint = latest_checkpoint(run_dir / CHECKPOINTS)
    if (run_dir / FINAL_MODEL).is_file():  # written last, after the final checkpoint
        check_final_files(run_dir)
        stats = run_dir / FINAL_VECNORMALIZE
        if checkpoint is not None:
            steps = checkpoint["timesteps"]
        else:
            steps = (read_state(run_dir) or {}).get("timesteps")
        return run_dir / FINAL_MODEL, stats if stats.is_file() else None, steps
    if checkpoint is None:
        raise ValueError(f"{run_dir} has neither {FINAL_MODEL} nor a checkpoint yet")
    entry = _read_entry(run_dir / CHECKPOINTS / LATEST)  # read whole by latest_checkpoint
    problem = None if entry is None else _problem(run_dir / CHECKPOINTS, entry)
    if problem is not None:
        raise ValueError(f"refusing to load the latest checkpoint: {problem}")
    if str(checkpoint.get("vecnormalize", "")).endswith(LEGACY_STATS_SUFFIX):
        raise ValueError(pickled_stats_message(checkpoint["vecnormalize"]))
    return checkpoint["model"], checkpoint.get("vecnormalize"), checkpoint["timesteps"]


def check_agent(controller: str, env_id: str, reads_frames: bool, observer: str) -> None:
    """ValueError unless the trained agent ``controller`` (``ALGO:DIR``) is a run of
    ``env_id`` with a model to load, trained on the unfiltered observer ``observer``
    (``--obs rgb``: "pixels"; ``--obs measurements``: "detections") iff ``reads_frames``;
    first, :class:`~observer_gym.extras.ExtraNotInstalled` without stable-baselines3 and
    PyTorch to load it."""
    spec = parse_agent_spec(controller)
    assert spec is not None, f"{controller!r} is not ALGO:DIR"  # the callers' check
    require_rl(f"agent {controller!r}")  # stable-baselines3 and PyTorch load it
    algo, run_dir = spec
    agent = read_config(run_dir, algo=algo)
    model_files(run_dir)
    if agent["env_id"] != env_id:
        raise ValueError(f"agent {controller!r} was trained on {agent['env_id']}, not {env_id}")
    wanted = UNFILTERED_OBSERVERS.get(agent["obs"])
    if (wanted is not None) != reads_frames or (wanted is not None and observer != wanted):
        unfiltered = " or ".join(repr(name) for name in UNFILTERED_OBSERVERS.values())
        wants = f"observer {wanted!r}" if wanted else f"an observer but {unfiltered}"
        raise ValueError(
            f"agent {controller!r} was trained with --obs {agent['obs']}: it needs {wants}, "
            f"got {observer!r}"
        )
