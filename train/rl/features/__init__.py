"""Observation features an agent may read besides its observation: the hyperparameter
``features: NAME`` of ``observer-gym train`` (default: none).

A feature set is a wrapper that replaces or extends the observation with quantities
computed from it and from the observer's ``info["estimate"]`` (its covariance; never the
ground truth), so the agent reads them from the true state and from an estimate alike.
Each system's sets live in the module of this package named after it; :data:`FEATURES`
lists them.
"""

from __future__ import annotations

import importlib

import gymnasium as gym

from observer_gym.envs import system_of

# system name -> feature set name -> the wrapper class in that system's module
FEATURES: dict[str, dict[str, str]] = {
    "ball_table": {"belief": "BeliefFeatures"},
    "ball_catcher": {"crossing": "CrossingFeatures"},
    "target_follower": {"tracking": "TrackingFeatures"},
}


def feature_names(system_name: str) -> tuple[str, ...]:
    """The feature sets of the system named ``system_name`` (its package name)."""
    return tuple(FEATURES.get(system_name, {}))


def wrap_features(env: gym.Env, name: str | None) -> gym.Env:
    """``env`` (an agent's env reading a state-layout vector) through the feature set
    ``name`` of its system; unchanged for None.

    Raises:
        ValueError: ``name`` is no feature set of the env's system (the message lists
            them), or the env's observation is not the state's layout.
    """
    if name is None:
        return env
    system = system_of(env)
    allowed = feature_names(system.name)
    if name not in allowed:
        listed = ", ".join(allowed) if allowed else "none"
        raise ValueError(f"unknown features {name!r} for {system.short_id}; allowed: {listed}")
    module = importlib.import_module(f"{__name__}.{system.name}")
    return getattr(module, FEATURES[system.name][name])(env)
