"""What the per-system consistency tests (tests/estimation/test_consistency_*.py) share:
issue 23's band, the sensor conditions every estimating observer is held to, one cell's
median episode NEES/dof, the cells still outside the band as strict expected failures,
and the check that ``r_scale`` refuses what is no positive number."""

from __future__ import annotations

from collections.abc import Collection, Iterable, Mapping

import pytest

from observer_gym.estimation import VisionObserver
from observer_gym.train.experiments.consistency_study import (
    SYSTEMS,
    ConsistencyRun,
    measure_consistency,
)

LOW, HIGH = 1.0 / 3.0, 3.0
CONDITIONS = {
    "0px": {"measurement_noise_px": 0.0},
    "0.5px": {"measurement_noise_px": 0.5},
    "2px": {"measurement_noise_px": 2.0},
    "drops": {"frame_drop_prob": 0.2},
    "latency": {"latency_s": 0.1},
}
NOT_POSITIVE = [0.0, -1.0, float("nan"), float("inf"), "x"]


def median_nees(
    env_id: str,
    observer: str,
    controller: str,
    episodes: int,
    steps: int | None,
    env_kwargs: Mapping,
    **options,
) -> float:
    """The median episode NEES/dof of ``episodes`` closed-loop episodes (seeds 0, 1, ...),
    printed with each episode's for ``pytest -s``."""
    run = measure_consistency(
        env_id, observer, controller, episodes, steps, env_kwargs, observer_options=options
    )
    print(f"\n{observer} {dict(env_kwargs)} {options}: NEES/dof {run.nees_ratios}")
    return run.median_nees_ratio


def study_cell(
    env_id: str, observer: str, env_options: Mapping, episodes: int, seed: int
) -> ConsistencyRun:
    """``observer``'s episodes in a consistency-study cell of ``env_id`` (its reference
    controller, step cap and env options, plus ``env_options``), seeds ``seed``,
    ``seed + 1``, ..., each episode's NEES/dof printed for ``pytest -s``."""
    study = SYSTEMS[env_id]
    run = measure_consistency(
        f"observer_gym/{env_id}",
        observer,
        study.controller,
        episodes,
        study.steps,
        {**study.env_kwargs, **env_options},
        seed=seed,
    )
    print(f"\n{env_id} {observer} {dict(env_options)}: NEES/dof {run.nees_ratios}")
    return run


def band_cells(
    cells: Iterable[tuple[str, str]],
    outside: Mapping[tuple[str, str], str],
    default_run: Collection[tuple[str, str]] | None = None,
) -> list:
    """(observer, condition) parameters, those in ``outside`` (measured outside the band)
    marked ``xfail(strict=True)`` with their reason: fixing one fails the test until its
    mark goes. Only the band's assertion is expected to fail: a cell whose episode raises
    (an observer's fault) fails the test. Given ``default_run`` (one cell per observer
    family, say), the other cells are marked ``slow``: CI's slow step runs them."""
    params = []
    for o, c in cells:
        marks = []
        if (o, c) in outside:
            marks.append(
                pytest.mark.xfail(strict=True, raises=AssertionError, reason=outside[(o, c)])
            )
        if default_run is not None and (o, c) not in default_run:
            marks.append(pytest.mark.slow)
        params.append(pytest.param(o, c, marks=marks) if marks else (o, c))
    if default_run is not None:
        unknown = set(default_run) - set(cells)
        assert not unknown, f"default_run names cells that are not: {sorted(unknown)}"
    return params


def assert_r_scale_refused(env, observers: Iterable[str], bad) -> None:
    """Every observer in ``observers`` refuses ``r_scale=bad`` with a ValueError naming it."""
    for observer in observers:
        with pytest.raises(ValueError, match="r_scale"):
            VisionObserver(env, observer=observer, r_scale=bad)
