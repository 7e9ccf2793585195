"""Validated, frozen configuration dataclasses for the environments.

Each env has one frozen dataclass filled from ``gym.make(id, **kwargs)``. Its fields are
declared with :func:`config_field`, which records the allowed range or choices and a
one-line description; validation happens on construction, so a bad value raises a
``ValueError`` naming the field, the value and what is allowed, before any world is built.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
from typing import Any


def config_field(default: Any, doc: str, *, low=None, high=None, choices=None):
    """A dataclass field with its allowed range (inclusive) or set of choices."""
    return dataclasses.field(
        default=default, metadata={"doc": doc, "low": low, "high": high, "choices": choices}
    )


def _check_value(name: str, value: Any, default: Any, meta: dict) -> None:
    choices = meta["choices"]
    if choices is not None:
        if value not in choices:
            raise ValueError(f"{name}={value!r} is not allowed; choose one of {list(choices)}")
        return
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ValueError(f"{name}={value!r} must be True or False")
        return
    if isinstance(default, (int, float)):
        low, high = meta["low"], meta["high"]
        allowed = f"allowed: [{low}, {high}]"
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"{name}={value!r} must be a number; {allowed}")
        if isinstance(default, int) and not isinstance(value, int):
            raise ValueError(f"{name}={value!r} must be an integer; {allowed}")
        if not math.isfinite(value):
            raise ValueError(f"{name}={value!r} must be finite; {allowed}")
        if (low is not None and value < low) or (high is not None and value > high):
            raise ValueError(f"{name}={value!r} is out of range; {allowed}")


def check_render_mode(render_mode: str | None, metadata: dict) -> None:
    """Raise ``ValueError`` unless ``render_mode`` is None or one of the env's
    ``metadata["render_modes"]``."""
    if render_mode is not None and render_mode not in metadata["render_modes"]:
        allowed = " or ".join(repr(m) for m in metadata["render_modes"])
        raise ValueError(f"render_mode={render_mode!r} is not supported; use None or {allowed}")


class EnvConfig:
    """Mixin for frozen dataclasses declared with :func:`config_field`."""

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            _check_value(f.name, getattr(self, f.name), f.default, f.metadata)

    @classmethod
    def from_kwargs(cls, **kwargs: Any):
        """Build from keyword arguments; an unknown keyword raises a ValueError."""
        names = [f.name for f in dataclasses.fields(cls)]
        for key in kwargs:
            if key not in names:
                close = difflib.get_close_matches(key, names, n=1)
                hint = f" Did you mean {close[0]!r}?" if close else ""
                raise ValueError(
                    f"{cls.__name__} has no option {key!r}.{hint} Options: {', '.join(names)}"
                )
        return cls(**kwargs)

    @classmethod
    def describe(cls) -> str:
        """One line per option: name, default, allowed values, description."""
        lines = []
        for f in dataclasses.fields(cls):
            meta = f.metadata
            if meta["choices"] is not None:
                allowed = " | ".join(repr(c) for c in meta["choices"])
            elif meta["low"] is not None or meta["high"] is not None:
                allowed = f"[{meta['low']}, {meta['high']}]"
            else:
                allowed = type(f.default).__name__
            lines.append(f"{f.name} = {f.default!r} ({allowed}): {meta['doc']}")
        return "\n".join(lines)
