"""A run's VecNormalize statistics as plain arrays, and the hashes of a finished run's
files: what loading an agent folder reads without unpickling anything.

stable-baselines3 saves its ``VecNormalize`` wrapper with ``pickle``, and unpickling a
file can run any code in it. A run therefore saves the wrapper's statistics and settings
as ``vecnormalize.npz`` (``checkpoints/vecnormalize_<N>.npz`` in a checkpoint): numpy
arrays only, read with ``allow_pickle=False`` (:func:`read_stats`), from which
:func:`build_vec_normalize` makes a new ``VecNormalize`` (the observations' running mean,
variance and count, per key for a Dict observation; the returns'; ``clip_obs``,
``clip_reward``, ``gamma``, ``epsilon``, ``norm_obs``, ``norm_reward``).

A finished run also writes ``final.json``: the sha256 of its ``model.zip`` and
``vecnormalize.npz`` (:func:`record_final_files`), which loading checks
(:func:`check_final_files`), as it checks a checkpoint's against its
``checkpoint_<N>.json``.

Folders written by earlier versions hold ``vecnormalize.pkl`` (``vecnormalize_<N>.pkl``):
loading refuses them in one line (:func:`pickled_stats_message`). Whoever trusts such a
folder converts it once::

    python -m observer_gym.train.rl.normalizer_file --trust-pickle DIR

which unpickles its statistics (running any code in them), writes the ``.npz`` files,
rewrites the checkpoint records to name them, writes ``final.json`` for a finished run and
removes the ``.pkl`` files (:func:`convert_folder`).
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import zipfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from observer_gym.envs.json_file import read_json

FINAL_STATS = "vecnormalize.npz"
PICKLED_FINAL_STATS = "vecnormalize.pkl"  # written by earlier versions
FINAL_RECORD = "final.json"  # a finished run's files and their sha256
CONFIG_FILE = "config.json"
CONFIG_SHA256 = "config_sha256"  # config.json's hash of the rest of itself
# how whoever trusts a folder without its recorded hashes records them (convert_folder)
VOUCH_COMMAND = "'python -m observer_gym.train.rl.normalizer_file --trust-pickle'"
STATS_FORMAT = "observer-gym VecNormalize statistics 1"
CONVERT_COMMAND = "python -m observer_gym.train.rl.normalizer_file --trust-pickle"
_MODEL = "model.zip"
_SCALARS = ("clip_obs", "clip_reward", "gamma", "epsilon")
_FLAGS = ("norm_obs", "norm_reward")


@dataclass(frozen=True)
class RunningStats:
    """A ``RunningMeanStd``: the running mean and variance of a stream and its count."""

    mean: np.ndarray
    var: np.ndarray
    count: float


@dataclass(frozen=True)
class NormalizerStats:
    """What a ``VecNormalize`` knows, as plain values.

    Attributes:
        obs: the observations' statistics; per key (those normalised) for a Dict
            observation; None when observations are not normalised.
        ret: the discounted returns' statistics (for the reward's scale).
        clip_obs, clip_reward, gamma, epsilon, norm_obs, norm_reward: VecNormalize's
            settings of the same names.
    """

    obs: RunningStats | dict[str, RunningStats] | None
    ret: RunningStats
    clip_obs: float
    clip_reward: float
    gamma: float
    epsilon: float
    norm_obs: bool
    norm_reward: bool


def _running(rms: Any) -> RunningStats:
    return RunningStats(
        np.asarray(rms.mean, dtype=np.float64).copy(),
        np.asarray(rms.var, dtype=np.float64).copy(),
        float(rms.count),
    )


def stats_of(vec_normalize: Any) -> NormalizerStats:
    """The statistics and settings of ``vec_normalize`` (SB3's ``VecNormalize``, or an
    object with its attributes, as unpickled from an old ``vecnormalize.pkl``)."""
    obs_rms = getattr(vec_normalize, "obs_rms", None)
    if isinstance(obs_rms, Mapping):
        obs: RunningStats | dict[str, RunningStats] | None = {
            str(k): _running(v) for k, v in obs_rms.items()
        }
    else:
        obs = None if obs_rms is None else _running(obs_rms)
    return NormalizerStats(
        obs=obs,
        ret=_running(vec_normalize.ret_rms),
        clip_obs=float(vec_normalize.clip_obs),
        clip_reward=float(vec_normalize.clip_reward),
        gamma=float(vec_normalize.gamma),
        epsilon=float(vec_normalize.epsilon),
        norm_obs=bool(vec_normalize.norm_obs),
        norm_reward=bool(vec_normalize.norm_reward),
    )


def _arrays(stats: NormalizerStats) -> dict[str, np.ndarray]:
    arrays = {"format": np.array(STATS_FORMAT)}
    for name in _SCALARS:
        arrays[name] = np.array(getattr(stats, name), dtype=np.float64)
    for name in _FLAGS:
        arrays[name] = np.array(getattr(stats, name), dtype=np.bool_)
    running = {"ret": stats.ret}
    if isinstance(stats.obs, dict):
        arrays["obs_keys"] = np.array(list(stats.obs), dtype=np.str_)
        running.update({f"obs.{key}": rms for key, rms in stats.obs.items()})
    elif stats.obs is not None:
        running["obs"] = stats.obs
    for prefix, rms in running.items():
        arrays[f"{prefix}.mean"] = rms.mean
        arrays[f"{prefix}.var"] = rms.var
        arrays[f"{prefix}.count"] = np.array(rms.count, dtype=np.float64)
    return arrays


def write_stats(stats: NormalizerStats, path: str | Path) -> None:
    """Write ``stats`` to ``path`` as an ``.npz`` of plain arrays (the name is kept as
    given: numpy adds no suffix)."""
    with open(path, "wb") as f:
        # numpy's stub types **kwds as if a key could be savez's allow_pickle flag
        np.savez(f, **_arrays(stats))  # type: ignore[arg-type]


def save_normalizer(vec_normalize: Any, path: str | Path) -> None:
    """Save ``vec_normalize``'s statistics to ``path`` (:func:`write_stats`), atomically
    (:func:`~observer_gym.train.core.atomic_write.replace_atomically`)."""
    from observer_gym.train.core.atomic_write import replace_atomically

    stats = stats_of(vec_normalize)
    replace_atomically(path, lambda tmp: write_stats(stats, tmp))


def pickled_stats_message(path: str | Path) -> str:
    """Why the pickled statistics at ``path`` are not loaded, and how to convert them."""
    path = Path(path)
    folder = path.parent.parent if path.parent.name == "checkpoints" else path.parent
    return (
        f"{path} holds VecNormalize statistics as a pickle (written by an earlier "
        "observer-gym), which can run code when loaded, so it is not loaded; if the folder "
        f"comes from a source you trust, convert it once with '{CONVERT_COMMAND} {folder}'"
    )


def _real(value: np.ndarray, name: str, path: Path) -> float:
    if value.shape != () or value.dtype.kind not in "fi" or not np.isfinite(value):
        raise ValueError(f"{path} is not a statistics file: {name} must be a finite number")
    return float(value)


def _flag(value: np.ndarray, name: str, path: Path) -> bool:
    if value.shape != () or value.dtype != np.bool_:
        raise ValueError(f"{path} is not a statistics file: {name} must be true or false")
    return bool(value)


def _read_running(arrays: Mapping[str, np.ndarray], prefix: str, path: Path) -> RunningStats:
    missing = [f"{prefix}.{k}" for k in ("mean", "var", "count") if f"{prefix}.{k}" not in arrays]
    if missing:
        raise ValueError(f"{path} is not a statistics file: it lacks {', '.join(missing)}")
    mean, var = arrays[f"{prefix}.mean"], arrays[f"{prefix}.var"]
    if mean.dtype.kind != "f" or var.dtype.kind != "f" or mean.shape != var.shape:
        raise ValueError(
            f"{path} is not a statistics file: {prefix}.mean and {prefix}.var must be float "
            "arrays of one shape"
        )
    if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(var)) and np.all(var >= 0)):
        raise ValueError(
            f"{path} is not a statistics file: {prefix}.mean must be finite and "
            f"{prefix}.var finite and >= 0"
        )
    count = _real(arrays[f"{prefix}.count"], f"{prefix}.count", path)
    return RunningStats(mean.astype(np.float64), var.astype(np.float64), count)


def read_stats(path: str | Path) -> NormalizerStats:
    """The statistics saved at ``path`` by :func:`write_stats`, read as plain arrays
    (``np.load`` with ``allow_pickle=False``: nothing in the file is run).

    Raises:
        ValueError: ``path`` is a pickle (``.pkl``, written by an earlier version: the
            message says how to convert it), missing, or not such a file.
    """
    path = Path(path)
    if path.suffix == ".pkl":
        raise ValueError(pickled_stats_message(path))
    try:
        loaded = np.load(path, allow_pickle=False)
        if not isinstance(loaded, np.lib.npyio.NpzFile):  # a single .npy array
            raise ValueError("one array, not an .npz archive")
        with loaded as npz:
            arrays = {name: npz[name] for name in npz.files}
    except FileNotFoundError:
        raise ValueError(f"{path} is missing") from None
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        reason = " ".join(str(exc).split())
        raise ValueError(f"{path} is not a statistics file of plain arrays ({reason})") from None
    fmt = arrays.get("format")
    if fmt is None or fmt.shape != () or str(fmt) != STATS_FORMAT:
        raise ValueError(f"{path} is not a statistics file: it does not say {STATS_FORMAT!r}")
    missing = [name for name in (*_SCALARS, *_FLAGS) if name not in arrays]
    if missing:
        raise ValueError(f"{path} is not a statistics file: it lacks {', '.join(missing)}")
    obs: RunningStats | dict[str, RunningStats] | None = None
    if "obs_keys" in arrays:
        keys = arrays["obs_keys"]
        if keys.ndim != 1 or keys.dtype.kind != "U":
            raise ValueError(f"{path} is not a statistics file: obs_keys must be a list of names")
        obs = {str(key): _read_running(arrays, f"obs.{key}", path) for key in keys}
    elif "obs.mean" in arrays:
        obs = _read_running(arrays, "obs", path)
    return NormalizerStats(
        obs=obs,
        ret=_read_running(arrays, "ret", path),
        clip_obs=_real(arrays["clip_obs"], "clip_obs", path),
        clip_reward=_real(arrays["clip_reward"], "clip_reward", path),
        gamma=_real(arrays["gamma"], "gamma", path),
        epsilon=_real(arrays["epsilon"], "epsilon", path),
        norm_obs=_flag(arrays["norm_obs"], "norm_obs", path),
        norm_reward=_flag(arrays["norm_reward"], "norm_reward", path),
    )


def _rms(running: RunningStats) -> Any:
    from stable_baselines3.common.running_mean_std import RunningMeanStd

    rms = RunningMeanStd(shape=running.mean.shape)
    rms.mean, rms.var, rms.count = running.mean.copy(), running.var.copy(), running.count
    return rms


def _check_observation_kind(stats: NormalizerStats, space: Any) -> None:
    """ValueError unless ``stats``' observation statistics are of ``space``'s kind: per key
    of a Dict space (keys it has), or one array for any other space."""
    from gymnasium import spaces

    if isinstance(space, spaces.Dict):
        if not isinstance(stats.obs, dict):
            raise ValueError(
                "the saved statistics are of one observation array; the env's observation "
                f"is a Dict with keys {sorted(space.spaces)}"
            )
        unknown = sorted(set(stats.obs) - set(space.spaces))
        if unknown:
            raise ValueError(
                f"the saved statistics are of observation keys {unknown} the env does not "
                f"have; its keys: {sorted(space.spaces)}"
            )
    elif isinstance(stats.obs, dict):
        raise ValueError(
            f"the saved statistics are per observation key ({sorted(stats.obs)}); the env's "
            "observation is one array"
        )


def build_vec_normalize(stats: NormalizerStats, venv: Any, training: bool) -> Any:
    """A new SB3 ``VecNormalize`` around ``venv`` holding ``stats``.

    Raises:
        ValueError: ``stats`` do not fit ``venv``'s observations (another shape, other
            keys).
    """
    from stable_baselines3.common.vec_env import VecNormalize

    keys = list(stats.obs) if isinstance(stats.obs, dict) else None
    norm_obs = stats.norm_obs and stats.obs is not None
    if norm_obs:
        _check_observation_kind(stats, venv.observation_space)
    vec_normalize = VecNormalize(
        venv,
        training=training,
        norm_obs=norm_obs,
        norm_reward=stats.norm_reward,
        clip_obs=stats.clip_obs,
        clip_reward=stats.clip_reward,
        gamma=stats.gamma,
        epsilon=stats.epsilon,
        norm_obs_keys=keys,
    )
    if norm_obs and stats.obs is not None:  # (norm_obs says it is not None)
        expected = vec_normalize.obs_rms
        given = stats.obs if isinstance(stats.obs, dict) else {None: stats.obs}
        current = expected if isinstance(expected, dict) else {None: expected}
        for key, running in given.items():
            if current[key].mean.shape != running.mean.shape:
                where = "the observation" if key is None else f"observation key {key!r}"
                raise ValueError(
                    f"the saved statistics of {where} have shape {running.mean.shape}, the "
                    f"env's {current[key].mean.shape}"
                )
        if isinstance(stats.obs, dict):
            vec_normalize.obs_rms = {key: _rms(running) for key, running in stats.obs.items()}
        else:
            vec_normalize.obs_rms = _rms(stats.obs)
    vec_normalize.ret_rms = _rms(stats.ret)
    return vec_normalize


def normalizer_for_spaces(stats: NormalizerStats, observation_space: Any, action_space: Any) -> Any:
    """A ``VecNormalize`` holding ``stats`` for a loaded agent, which normalises the
    observations it is given (``normalize_obs``) and steps no env: it wraps a vector env
    of one stand-in env with these spaces."""
    import gymnasium as gym
    from stable_baselines3.common.vec_env import DummyVecEnv

    class _Spaces(gym.Env):
        def __init__(self) -> None:
            self.observation_space, self.action_space = observation_space, action_space

    return build_vec_normalize(stats, DummyVecEnv([_Spaces]), training=False)


# --- a finished run's hashes -----------------------------------------------------------
def config_sha256(config: Mapping[str, Any]) -> str:
    """The sha256 of ``config`` (without :data:`CONFIG_SHA256`) as canonical JSON."""
    import json

    from observer_gym.train.reports.outputs import to_jsonable

    body = {k: v for k, v in to_jsonable(config).items() if k != CONFIG_SHA256}
    text = json.dumps(body, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()


def sha256_of(path: str | Path) -> str:
    """The sha256 of the file ``path``."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(1 << 20):
            digest.update(block)
    return digest.hexdigest()


def record_final_files(run_dir: str | Path) -> None:
    """Write ``run_dir/final.json``: the sha256 of its ``model.zip`` and, if there, its
    ``vecnormalize.npz``."""
    from observer_gym.train.reports.outputs import write_json_atomic

    run_dir = Path(run_dir)
    names = [name for name in (_MODEL, FINAL_STATS) if (run_dir / name).is_file()]
    write_json_atomic(
        run_dir / FINAL_RECORD, {"sha256": {name: sha256_of(run_dir / name) for name in names}}
    )


def check_final_files(run_dir: str | Path) -> None:
    """ValueError unless the finished run's files in ``run_dir`` are those recorded in its
    ``final.json`` (each file named there present with its sha256), and its statistics
    are no pickle. A ``model.zip`` without final.json (deleted, or written by a version
    that recorded none) is refused: whoever trusts the folder records it with
    :func:`convert_folder`."""
    run_dir = Path(run_dir)
    if (run_dir / PICKLED_FINAL_STATS).is_file() and not (run_dir / FINAL_STATS).is_file():
        raise ValueError(pickled_stats_message(run_dir / PICKLED_FINAL_STATS))
    path = run_dir / FINAL_RECORD
    if not path.exists():
        if (run_dir / _MODEL).exists():
            raise ValueError(
                f"{run_dir} has {_MODEL} but no {FINAL_RECORD} recording its sha256: an "
                "untrusted folder, refused before anything is loaded (loading a model "
                "unpickles part of it); if it comes from a source you trust, record its "
                f"files with {VOUCH_COMMAND} {run_dir}"
            )
        return
    try:
        recorded = read_json(path)["sha256"]
        if not isinstance(recorded, dict):
            raise TypeError
    except (OSError, ValueError, KeyError, TypeError):
        raise ValueError(f"{path} is damaged: not the record of a finished run's files") from None
    if _MODEL not in recorded or (
        (run_dir / FINAL_STATS).is_file() and FINAL_STATS not in recorded
    ):
        raise ValueError(f"{path} does not record {_MODEL} and {FINAL_STATS} as {run_dir} has them")
    for name, digest in recorded.items():
        if name not in (_MODEL, FINAL_STATS):
            raise ValueError(f"{path} names {name!r}, no file of a finished run")
        file = run_dir / name
        if not file.is_file():
            raise ValueError(f"{file} is missing (recorded in {path})")
        if sha256_of(file) != digest:
            raise ValueError(
                f"{file} is not the file the run saved (its sha256 differs from the one "
                f"recorded in {path}); refusing to load it: restore the folder from its "
                "source, or train the agent again"
            )


# --- converting a folder of an earlier version ------------------------------------------
def _unpickle(path: Path) -> NormalizerStats:
    import pickle

    try:
        with open(path, "rb") as f:
            loaded = pickle.load(f)  # trusted by the caller: this runs the file's code
        return stats_of(loaded)
    except (pickle.UnpicklingError, EOFError, AttributeError, ImportError, TypeError) as exc:
        # a damaged pickle, or one that is not a VecNormalize
        raise ValueError(
            f"{path} holds no VecNormalize statistics: {type(exc).__name__}: "
            f"{' '.join(str(exc).split())}"
        ) from None


def _convert_checkpoints(directory: Path) -> list[Path]:
    """Convert the pickled statistics named by the checkpoint records in ``directory``,
    and record the sha256 of the files of a record that has none (vouching for them as
    they are now); returns the pickles converted (to remove)."""
    from observer_gym.train.reports.outputs import write_json_atomic

    converted: dict[str, str] = {}  # pickle name -> npz name
    records = [*sorted(directory.glob("checkpoint_*.json")), directory / "latest.json"]
    for record in records:
        try:
            entry = read_json(record)
        except (OSError, ValueError):
            continue  # no record, or a damaged one: resume passes it over as before
        if not isinstance(entry, dict):
            continue
        changed = False
        old = entry.get("vecnormalize")
        if isinstance(old, str) and old.endswith(".pkl"):
            new = old.removesuffix(".pkl") + ".npz"
            if old not in converted and (directory / old).is_file():
                digest = (entry.get("sha256") or {}).get(old)
                if digest is not None and sha256_of(directory / old) != digest:
                    raise ValueError(
                        f"{directory / old} is damaged (its sha256 differs from the one in "
                        f"{record}); not converted"
                    )
                write_stats(_unpickle(directory / old), directory / new)
                converted[old] = new
            if old in converted:  # (else its pickle is gone: the checkpoint stays as it is)
                entry["vecnormalize"] = new
                if isinstance(entry.get("sha256"), dict):
                    entry["sha256"].pop(old, None)
                    entry["sha256"][new] = sha256_of(directory / new)
                changed = True
        if "sha256" not in entry:
            names = [v for k, v in entry.items() if k != "timesteps" and isinstance(v, str)]
            if all((directory / name).is_file() for name in names):
                entry["sha256"] = {name: sha256_of(directory / name) for name in names}
                changed = True
        if changed:
            write_json_atomic(record, entry)
    return [directory / old for old in converted]


def convert_folder(run_dir: str | Path) -> list[Path]:
    """Convert the run in ``run_dir`` (or every seed's run of a multi-seed folder) from
    pickled statistics to ``.npz`` files: its final ``vecnormalize.pkl`` and those of
    its checkpoints. Writes ``final.json`` for a finished run that has none and the
    ``config_sha256`` of a config.json that records none (vouching for the ``model.zip``
    and the config as they are now) and removes the converted pickles. Returns the ``.npz``
    files written.

    Unpickling runs whatever code the files hold: call this only on a folder from a
    source you trust.

    Raises:
        ValueError: ``run_dir`` is no folder, holds no run, or a checkpoint's pickle
            does not match its recorded sha256.
    """
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise ValueError(f"{run_dir} is no folder")
    seeds = sorted(p for p in run_dir.glob("seed_*") if (p / "config.json").is_file())
    if not (run_dir / "config.json").is_file():
        if not seeds:
            raise ValueError(f"{run_dir} holds no observer-gym training run (no config.json)")
        return [path for seed in seeds for path in convert_folder(seed)]
    written: list[Path] = []
    pickles: list[Path] = []
    if (run_dir / "checkpoints").is_dir():
        pickles += _convert_checkpoints(run_dir / "checkpoints")
        written += [p.with_suffix(".npz") for p in pickles]
    final = run_dir / PICKLED_FINAL_STATS
    if final.is_file():
        write_stats(_unpickle(final), run_dir / FINAL_STATS)
        written.append(run_dir / FINAL_STATS)
        pickles.append(final)
    if (run_dir / _MODEL).is_file() and (pickles or not (run_dir / FINAL_RECORD).exists()):
        record_final_files(run_dir)
    _record_config_sha256(run_dir)
    for path in pickles:
        path.unlink(missing_ok=True)
    return written


def _record_config_sha256(run_dir: Path) -> None:
    """Add :data:`CONFIG_SHA256` to ``run_dir``'s config.json if it records none (vouching
    for it as it is now)."""
    from observer_gym.train.reports.outputs import write_json_atomic

    config = read_json(run_dir / CONFIG_FILE)
    if isinstance(config, dict) and CONFIG_SHA256 not in config:
        write_json_atomic(run_dir / CONFIG_FILE, {**config, CONFIG_SHA256: config_sha256(config)})


class _OneLineParser(argparse.ArgumentParser):
    """A parser whose usage mistakes are one line on stderr and exit status 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        print(f"{self.prog}: error: {message}", file=sys.stderr)
        raise SystemExit(2)


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m observer_gym.train.rl.normalizer_file --trust-pickle DIR [DIR ...]``."""
    parser = _OneLineParser(
        prog="python -m observer_gym.train.rl.normalizer_file",
        description=(
            "Convert run folders written by an earlier observer-gym, whose VecNormalize "
            "statistics are pickles (vecnormalize.pkl), to plain-array .npz files that load "
            "without running code; writes final.json (the sha256 of model.zip and the "
            "statistics) and removes the pickles; records the hashes a folder lacks (final.json, "
            "config_sha256, the checkpoints' sha256). Unpickling runs whatever code the files "
            "hold: convert only folders from a source you trust, which --trust-pickle says."
        ),
    )
    parser.add_argument("folders", nargs="+", type=Path, metavar="DIR", help="run folders")
    parser.add_argument(
        "--trust-pickle",
        action="store_true",
        help="required: you trust these folders' pickles (they are unpickled)",
    )
    args = parser.parse_args(argv)
    prog = parser.prog
    if not args.trust_pickle:
        print(
            f"{prog}: error: unpickling runs the files' code: give --trust-pickle to convert "
            "folders from a source you trust",
            file=sys.stderr,
        )
        return 2
    from observer_gym.train.reports.folder_lock import (
        FOLDER_BUSY_EXIT_CODE,
        FolderBusyError,
        folder_lock,
    )

    for folder in args.folders:
        try:
            if not folder.is_dir():
                raise ValueError(f"{folder} is no folder")
            with folder_lock(folder, "convert statistics"):  # no command writes it meanwhile
                written = convert_folder(folder)
        except ValueError as exc:
            print(f"{prog}: error: {exc}", file=sys.stderr)
            return 2
        except FolderBusyError as exc:
            print(f"{prog}: error: {exc}", file=sys.stderr)
            return FOLDER_BUSY_EXIT_CODE
        except OSError as exc:
            print(f"{prog}: error: {exc}", file=sys.stderr)
            return 1
        print(f"{folder}: {len(written)} statistics file(s) converted")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
