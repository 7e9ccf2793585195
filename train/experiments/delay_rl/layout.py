"""Where a random-delay study keeps what (the folder's layout; see :mod:`.run`)."""

from __future__ import annotations

from pathlib import Path

PLAN_FILE = "study.json"
DELIVERY_FILE = "delivery.json"
TIMING_FILE = "timing.json"  # each invocation's wall time, for the budget


def cell_dir(out_dir: Path, level: str, name: str) -> Path:
    """The multi-seed training folder of input ``name`` trained at ``level``."""
    return out_dir / "train" / level / name


def eval_path(out_dir: Path, trained_at: str, name: str, at: str) -> Path:
    """The evaluation record of those agents at level ``at``."""
    return out_dir / "eval" / trained_at / name / f"at_{at}.json"


def reference_path(out_dir: Path, name: str, at: str) -> Path:
    """The classical controller's record on input ``name``'s belief at level ``at``."""
    return out_dir / "reference" / name / f"at_{at}.json"
