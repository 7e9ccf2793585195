"""An agent with its own camera: options in the default camera's pixels in the agent's.

An option whose name ends in ``_px`` (``measurement_noise_px``,
``calib_principal_point_error_px``) is in pixels of the camera it acts on. An agent
trained with its own, smaller camera (``ppo:ball_table-rgb`` at 84 x 84: a focal length of
42 px against 160) would meet 2 px of principal-point error as 48 mrad of view where
every other entry meets 12.5 mrad. The benchmark (each level's options) and ``compare``,
``run`` and ``sweep`` (the request's ``--env-option`` and a sweep's varied options) give
such an agent each pixel-valued option times its camera's scale (the agent's focal length
over the default's), so every entry meets the same angles. A metric in pixels needs no
scaling here: the task reports it in the default camera's pixels
(:func:`observer_gym.train.core.tasks.target_follower.default_camera_factors`).

The scale comes from the cameras the episodes will have (``camera_intrinsics()`` of the
env built with and without the agent's env options); a camera that is not the default
scaled as a whole (x and y, every camera alike) is refused, since no single factor
translates the options to it.
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Mapping
from typing import Any

PIXEL_SUFFIX = "_px"  # names say units: an option ending so is in pixels
# the camera's own geometry, in its own pixels: what makes the agent's camera, not an
# amount to translate
CAMERA_GEOMETRY_OPTIONS = frozenset(
    {"image_width_px", "image_height_px", "fx_px", "fy_px", "cx_px", "cy_px"}
)
RELATIVE_TOLERANCE = 1e-9


def is_pixel_valued(name: str) -> bool:
    """Whether the option ``name`` is an amount in the camera's pixels (a noise, an error,
    a set point such as ``desired_width_px``), not the camera's own geometry."""
    return name.endswith(PIXEL_SUFFIX) and name not in CAMERA_GEOMETRY_OPTIONS


def _focal_lengths_px(env_id: str, env_options: Mapping[str, Any]) -> list[tuple[float, float]]:
    """Each camera's nominal (fx, fy) with ``env_options`` (builds the env, then closes
    it)."""
    import gymnasium as gym

    import observer_gym.envs  # noqa: F401  (registers the envs)

    env = gym.make(env_id, **env_options)
    try:
        return [(k.fx_px, k.fy_px) for k in env.unwrapped.camera_intrinsics()]  # type: ignore[attr-defined]
    finally:
        env.close()


def camera_scale(env_id: str, agent_env_options: Mapping[str, Any]) -> float:
    """The entry's focal length over the default camera's (1.0 if the agent's options
    leave the camera as it is); computed once per env and options (it builds two envs).

    Raises:
        ValueError: the agent's camera is not the default scaled as a whole (x and y of
            every camera by one factor), naming the factors found.
    """
    if not agent_env_options:
        return 1.0
    return _camera_scale(env_id, json.dumps(dict(agent_env_options), sort_keys=True))


@functools.cache
def _camera_scale(env_id: str, agent_env_options_json: str) -> float:
    agent_env_options = json.loads(agent_env_options_json)
    default = _focal_lengths_px(env_id, {})
    own = _focal_lengths_px(env_id, agent_env_options)
    ratios = [
        own_f / default_f
        for own_fs, default_fs in zip(own, default, strict=True)
        for own_f, default_f in zip(own_fs, default_fs, strict=True)
    ]
    scale = ratios[0]
    if not all(math.isclose(r, scale, rel_tol=RELATIVE_TOLERANCE) for r in ratios):
        raise ValueError(
            f"the agent's env options {dict(agent_env_options)} change the camera's focal "
            f"lengths by the factors {[round(r, 6) for r in ratios]} (fx, fy per camera); "
            "pixel-valued options translate only to a camera scaled as a whole "
            "(one factor for x and y of every camera)"
        )
    return 1.0 if math.isclose(scale, 1.0, rel_tol=RELATIVE_TOLERANCE) else scale


def options_in_entry_pixels(options: Mapping[str, Any], scale: float) -> dict[str, Any]:
    """``options`` with each pixel-valued number times ``scale`` (the entry's camera)."""
    if scale == 1.0:
        return dict(options)
    return {
        key: value * scale
        if is_pixel_valued(key) and isinstance(value, int | float) and not isinstance(value, bool)
        else value
        for key, value in options.items()
    }
