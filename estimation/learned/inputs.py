"""What every learned observer requires of its env (no torch here)."""

from __future__ import annotations

from typing import Any

__all__ = ["require_measurements"]


def require_measurements(env: Any, owner: str) -> None:
    """ValueError in one line unless ``env`` (an unwrapped camera env) is in measurements
    mode: every shipped network is trained on the perfect detector's measurements, none
    on rendered frames. ``owner`` names the observer ("learned-kf of BallTable-v0")."""
    obs_mode = env.config.obs_mode
    if obs_mode != "measurements":
        raise ValueError(
            f"{owner} reads the perfect detector's measurements only (its -measurements "
            f"name): its network is not trained on rendered frames (obs_mode {obs_mode!r})"
        )
