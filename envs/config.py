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
import reprlib
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np


def config_field(default: Any, doc: str, *, low=None, high=None, choices=None):
    """A dataclass field with its allowed range (inclusive) or set of choices."""
    return dataclasses.field(
        default=default, metadata={"doc": doc, "low": low, "high": high, "choices": choices}
    )


def _short(value: Any) -> str:
    """``repr(value)``, shortened for an error message (a 400-digit int, a long list)."""
    return reprlib.repr(value)


def _is_real(value: Any) -> bool:
    """A real number: Python's or NumPy's int or float (not bool, complex or str)."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(
        value, (bool, np.bool_)
    )


def real_number(name: str, value: Any, low: float | None, high: float | None) -> float:
    """``value`` as a float, or ValueError naming ``name``, the value and the range."""
    allowed = f"allowed: [{low}, {high}]"
    if not _is_real(value):
        raise ValueError(f"{name}={_short(value)} must be a number; {allowed}")
    try:
        number = float(value)
    except OverflowError:
        raise ValueError(f"{name}={_short(value)} must be finite; {allowed}") from None
    if not math.isfinite(number):
        raise ValueError(f"{name}={_short(value)} must be finite; {allowed}")
    if (low is not None and number < low) or (high is not None and number > high):
        raise ValueError(f"{name}={_short(value)} is out of range; {allowed}")
    return number


def real_array(name: str, value: Any, shape: tuple[int, ...], bound: float) -> np.ndarray:
    """``value`` as a float array of ``shape`` with every entry finite and within
    +-``bound``, or ValueError naming ``name``, the value and what is allowed."""
    count = " x ".join(str(n) for n in shape)
    error = ValueError(
        f"{name} must be {count} finite numbers within +-{bound:g}, got {_short(value)}"
    )
    if isinstance(value, np.ma.MaskedArray):
        raise error
    try:
        raw = np.asarray(value)
    except (TypeError, ValueError):  # ragged sequences
        raise error from None
    if raw.dtype.kind not in "iuf" or raw.shape != shape:
        raise error
    array = raw.astype(np.float64)
    if not np.all(np.isfinite(array)) or np.any(np.abs(array) > bound):
        raise error
    return array


def _checked_value(name: str, value: Any, default: Any, meta: Mapping[str, Any]) -> Any:
    """``value`` in its field's Python type (NumPy scalars become int, float or bool), or
    ValueError naming the field, the value and what is allowed."""
    choices = meta["choices"]
    if choices is not None:
        # Only a value of a choice's type: ``value in choices`` would take an array that
        # compares equal elementwise (np.array(["fixed"])) or raise an unnamed ValueError.
        matches = [c for c in choices if isinstance(value, type(c)) and value == c]
        if not matches:
            raise ValueError(
                f"{name}={_short(value)} is not allowed; choose one of {list(choices)}"
            )
        return matches[0]  # the choice itself (np.str_("rgb") becomes "rgb")
    if isinstance(default, bool):
        if not isinstance(value, (bool, np.bool_)):
            raise ValueError(f"{name}={_short(value)} must be True or False")
        return bool(value)
    if isinstance(default, (int, float)):
        low, high = meta["low"], meta["high"]
        if isinstance(default, int):
            if not isinstance(value, (int, np.integer)) or isinstance(value, (bool, np.bool_)):
                raise ValueError(
                    f"{name}={_short(value)} must be an integer; allowed: [{low}, {high}]"
                )
            if (low is not None and value < low) or (high is not None and value > high):
                raise ValueError(
                    f"{name}={_short(value)} is out of range; allowed: [{low}, {high}]"
                )
            return int(value)
        return real_number(name, value, low, high)
    return value


def check_render_mode(render_mode: str | None, metadata: dict) -> None:
    """Raise ``ValueError`` unless ``render_mode`` is None or one of the env's
    ``metadata["render_modes"]``."""
    if render_mode is not None and render_mode not in metadata["render_modes"]:
        allowed = " or ".join(repr(m) for m in metadata["render_modes"])
        raise ValueError(f"render_mode={render_mode!r} is not supported; use None or {allowed}")


class EnvConfig:
    """Mixin for frozen dataclasses declared with :func:`config_field`."""

    __dataclass_fields__: ClassVar[dict[str, dataclasses.Field[Any]]]  # set by @dataclass

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = _checked_value(f.name, getattr(self, f.name), f.default, f.metadata)
            object.__setattr__(self, f.name, value)  # frozen: NumPy scalars made Python

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
