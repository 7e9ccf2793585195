"""What every learned observer requires of its env (no torch here)."""

from __future__ import annotations

from typing import Any

__all__ = ["require_frames_or_measurements"]


def require_frames_or_measurements(env: Any, owner: str) -> str:
    """``env``'s obs_mode if it is "rgb" (frames through the system's learned detector) or
    "measurements" (the perfect detector's); ValueError in one line otherwise."""
    obs_mode: str = env.config.obs_mode
    if obs_mode not in ("rgb", "measurements"):
        raise ValueError(
            f"{owner} reads camera frames (obs_mode 'rgb') or the perfect detector's "
            f"measurements (obs_mode 'measurements'), not obs_mode {obs_mode!r}"
        )
    return obs_mode
