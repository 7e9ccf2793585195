"""The closed loop the estimation tests run: a controller acting on an observer's
estimate, step by step, for each seed; each test reads from the steps what it checks."""

from __future__ import annotations

import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping
from typing import Any, NamedTuple

import gymnasium as gym
import numpy as np

from observer_gym.controllers import make_controller
from observer_gym.estimation import VisionObserver


class Step(NamedTuple):
    """One step of the loop: the seed of its episode, the estimate the controller reads
    next, the env's flags and its info."""

    seed: int
    estimate: np.ndarray
    terminated: bool
    truncated: bool
    info: dict[str, Any]


def closed_loop(
    make_env: Callable[[], gym.Env],
    controller: str,
    seeds: Iterable[int],
    steps: int,
    *,
    deterministic: bool = True,
    reset_options: Mapping[str, Any] | None = None,
    quiet: tuple[type[Warning], ...] = (),
    **observer_kwargs,
) -> Iterator[Step]:
    """``controller`` (by name) on the estimate of ``VisionObserver(make_env(),
    **observer_kwargs)`` for ``steps`` steps from ``reset(seed=seed)`` of each seed, each
    episode in a new env, closed when the episode ends or the caller stops; the warnings of
    the ``quiet`` categories from the controller are silenced."""
    for seed in seeds:
        env = VisionObserver(make_env(), **observer_kwargs)
        try:
            policy = make_controller(controller, env)
            options = None if reset_options is None else dict(reset_options)
            estimate, info = env.reset(seed=seed, options=options)
            for _ in range(steps):
                with warnings.catch_warnings():
                    for category in quiet:
                        warnings.simplefilter("ignore", category)
                    action, _ = policy.predict(estimate, deterministic=deterministic)
                estimate, _, terminated, truncated, info = env.step(action)
                yield Step(seed, estimate, terminated, truncated, info)
        finally:
            env.close()
