"""The options the env suite (tests/envs) sets for an env, declared by the env itself.

The suite checks properties that every env must have (determinism, copies, pairing across
observation modes, ...) under each env's random disturbances. Which options switch those
on differs per env, so each env class carries a :class:`SuiteKnobs` as ``suite_knobs``
and the suite reads it: a new system passes the suite with no edit to the tests.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, NamedTuple


class SuiteKnobs(NamedTuple):
    """Env options for the env suite, each a ``gym.make`` keyword mapping."""

    # switch every random draw of the world on (pushes, occluders, random camera offsets)
    # and frame drops, so that their draws are part of what must repeat and be copied
    disturbed: Mapping[str, Any]
    # noise in the "measurements" mode
    measurement_noise: Mapping[str, Any]
    # what the pairing test adds: the rest of the disturbances, image noise for "rgb",
    # and a small image where the image size does not change the world
    paired: Mapping[str, Any]
