"""The trained agents shipped in the package: ``train/rl/agents/<system>-<obs>/``, each a run
folder cut down to what loading needs (``config.json``, ``model.zip``,
``vecnormalize.npz`` if it normalises, ``final.json`` with the sha256 of both, checked on
every load, ``state.json``), with ``README.md`` (the command and seed that trained it and
how good it is) and ``fingerprint.json`` (an observation and the action the agent gives
for it, which a test checks on every install).

Wherever a trained agent is named as ``ALGO:DIR``, ``ALGO:NAME`` names a shipped one
(``ppo:ball_table-estimate``) when no folder ``NAME`` exists
(:func:`observer_gym.train.rl.run_dir.parse_agent_spec`). This module only finds the
folders; :mod:`observer_gym.train.rl.ship_agent` copies a run into the package and writes
its fingerprint.
"""

from __future__ import annotations

from pathlib import Path

SHIPPED_DIR = Path(__file__).parent / "agents"
FINGERPRINT_FILE = "fingerprint.json"
README_FILE = "README.md"


def shipped_names() -> tuple[str, ...]:
    """The names of the shipped agents (their folders under :data:`SHIPPED_DIR`), sorted."""
    if not SHIPPED_DIR.is_dir():
        return ()
    return tuple(sorted(p.name for p in SHIPPED_DIR.iterdir() if (p / "config.json").is_file()))


def shipped_path(name: str) -> Path | None:
    """The folder of the shipped agent ``name`` (``ball_table-estimate``), or None if no
    agent of that name is shipped."""
    if name not in shipped_names():
        return None
    return SHIPPED_DIR / name
