"""A benchmark run's per-episode records, ``episodes.csv``: one row per episode with its
level, index, seed and the headline metric's value.

The values are written with ``repr`` (the shortest text that reads back as the same
float), so ``benchmark --check`` re-derives the scores from the file bit for bit.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

from observer_gym.envs.json_file import read_bytes_limited

MAX_CSV_BYTES = 256 * 1024 * 1024  # an official run's records are a few hundred kB

EPISODES_CSV = "episodes.csv"
COLUMNS = ("level", "episode", "seed")


class EpisodeRecord(NamedTuple):
    """One episode of a benchmark run."""

    level: str
    episode: int  # its index within the level
    seed: int
    value: float  # the headline metric (a catch: 1.0 or 0.0)


def metric_value(value: object, metric: str, where: str) -> float:
    """An episode's headline metric as a finite float (True/False as 1.0/0.0);
    ValueError naming ``where`` for anything else (None: the episode had none)."""
    if isinstance(value, bool):
        return float(value)
    if isinstance(value, int | float) and math.isfinite(value):
        return float(value)
    raise ValueError(f"{where}: its {metric} is {value!r}, not a finite number")


def csv_text(records: Sequence[EpisodeRecord], metric: str) -> str:
    """The text of ``episodes.csv`` for ``records``."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow([*COLUMNS, metric])
    for r in records:
        writer.writerow([r.level, r.episode, r.seed, repr(r.value)])
    return out.getvalue()


def read_csv(path: Path, metric: str) -> list[EpisodeRecord]:
    """The records in ``path``; ValueError naming the file, the line and what is wrong
    (a missing file, no regular file or one larger than :data:`MAX_CSV_BYTES`, another
    header, a malformed row)."""
    try:  # a regular file of at most MAX_CSV_BYTES (not a link to /dev/zero)
        text = read_bytes_limited(path, MAX_CSV_BYTES).decode("utf-8")
    except OSError as exc:
        raise ValueError(f"{path}: cannot be read: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: cannot be read: not UTF-8 text ({exc.reason})") from None
    rows = list(csv.reader(io.StringIO(text)))
    header = [*COLUMNS, metric]
    if not rows or rows[0] != header:
        got = rows[0] if rows else "nothing"
        raise ValueError(f"{path}: line 1 is {got}, not the header {header}")
    records = []
    for line, row in enumerate(rows[1:], start=2):
        try:
            level, episode, seed, value = row
            record = EpisodeRecord(level, int(episode), int(seed), float(value))
        except ValueError:
            raise ValueError(
                f"{path}: line {line} is {row}, not level,episode,seed,{metric}"
            ) from None
        if not math.isfinite(record.value):
            raise ValueError(f"{path}: line {line}: {metric} is {value!r}, not finite")
        records.append(record)
    return records
