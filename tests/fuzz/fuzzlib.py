"""What the fuzz tests share: the tally of what they tried, and Hypothesis strategies for
junk values, config values (derived from each config dataclass's ``config_field``
metadata) and actions.

The tally: every example a property tries is recorded with :func:`record` under a
category ("config: BallTableConfig", "action: BallCatcher-v1", ...) as accepted or
rejected (ValueError); tests/fuzz/conftest.py prints the table at the end of the run
(gathered from every xdist worker).
"""

from __future__ import annotations

import dataclasses
import math
from collections import Counter
from typing import Any

import numpy as np
from hypothesis import event
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

# (category, "accepted" | "rejected") -> count
COUNTS: Counter[tuple[str, str]] = Counter()


def record(category: str, accepted: bool) -> None:
    outcome = "accepted" if accepted else "rejected"
    COUNTS[(category, outcome)] += 1
    event(f"{category}: {outcome}")


# --- junk -------------------------------------------------------------------------------
NUMERIC_DTYPES = (
    np.int8,
    np.int16,
    np.int32,
    np.int64,
    np.uint8,
    np.uint16,
    np.uint32,
    np.uint64,
    np.float16,
    np.float32,
    np.float64,
)
ODD_DTYPES = (np.bool_, np.complex64, np.complex128, np.str_, np.bytes_, np.datetime64)


def numpy_arrays(shape=None, dtypes=NUMERIC_DTYPES + ODD_DTYPES) -> st.SearchStrategy:
    """NumPy arrays of any of ``dtypes``, of ``shape`` (default: small random shapes),
    with any values of the dtype (NaN and inf included)."""
    shapes = st.just(shape) if shape is not None else hnp.array_shapes(min_dims=0, max_dims=3)
    return st.sampled_from(dtypes).flatmap(
        lambda dtype: hnp.arrays(np.dtype(dtype), shapes, elements=_elements(dtype))
    )


def _elements(dtype) -> st.SearchStrategy | None:
    if dtype is np.datetime64:
        return None
    # NumPy drops trailing NUL characters, which Hypothesis refuses
    if dtype is np.str_:
        return st.text(st.characters(exclude_characters="\x00"), max_size=4)
    if dtype is np.bytes_:
        return st.binary(max_size=4).filter(lambda b: not b.endswith(b"\x00"))
    return None  # the dtype's full range, NaN and inf included for floats


def special_floats() -> st.SearchStrategy:
    return st.sampled_from([math.nan, math.inf, -math.inf, -0.0, 1e308, -1e308, 5e-324])


def numpy_scalars() -> st.SearchStrategy:
    return st.sampled_from((*NUMERIC_DTYPES, np.bool_, np.complex128)).flatmap(
        lambda dtype: hnp.from_dtype(np.dtype(dtype)).map(lambda v: np.dtype(dtype).type(v))
    )


def junk() -> st.SearchStrategy:
    """Any value a caller might pass by mistake."""
    scalar = st.one_of(
        st.none(),
        st.booleans(),
        st.integers(),
        st.sampled_from([10**400, -(10**400), 2**63, 2**64]),
        st.floats(),
        special_floats(),
        st.complex_numbers(),
        st.text(max_size=8),
        st.binary(max_size=4),
        numpy_scalars(),
    )
    containers = st.recursive(
        scalar,
        lambda inner: st.one_of(
            st.lists(inner, max_size=4),
            st.tuples(inner, inner),
            st.dictionaries(st.text(max_size=4), inner, max_size=2),
        ),
        max_leaves=8,
    )
    return st.one_of(
        containers,
        numpy_arrays(),
        numpy_arrays().map(lambda a: np.ma.masked_array(a, mask=np.zeros(a.shape, bool))),
        st.lists(st.floats(), max_size=4).map(lambda v: np.array(v, dtype=object)),
        st.just(object()),
        st.frozensets(st.integers(), max_size=3),
    )


# --- config values ----------------------------------------------------------------------
def _in_range(number: float, meta: dict) -> bool:
    low, high = meta["low"], meta["high"]
    return (low is None or number >= low) and (high is None or number <= high)


def _int_kinds(value: int) -> list:
    """``value`` as Python's int and every NumPy integer type that holds it."""
    kinds = [value]
    for dtype in (np.int8, np.int16, np.int32, np.int64, np.uint8, np.uint16, np.uint64):
        info = np.iinfo(dtype)
        if info.min <= value <= info.max:
            kinds.append(dtype(value))
    return kinds


def field_values(field: dataclasses.Field) -> st.SearchStrategy:
    """(value, valid) pairs for one config field: valid means the field's own check
    (type, range, choices) passes; cross-field rules may still refuse it."""
    meta, default = field.metadata, field.default
    choices = meta["choices"]
    if choices is not None:
        valid = st.sampled_from(list(choices)).map(lambda v: (v, True))
        wrong = junk().filter(lambda v: not _is_choice(v, choices)).map(lambda v: (v, False))
        near = st.sampled_from(list(choices)).map(lambda v: (v.upper() + " ", False))
        return st.one_of(valid, near, wrong)
    if isinstance(default, bool):
        valid = st.sampled_from([True, False, np.True_, np.False_]).map(lambda v: (v, True))
        wrong = st.one_of(
            st.sampled_from([0, 1, 0.0, 1.0, "True", "false", None, [True], np.int64(1)]),
            junk().filter(lambda v: not isinstance(v, (bool, np.bool_))),
        ).map(lambda v: (v, False))
        return st.one_of(valid, wrong)
    low, high = meta["low"], meta["high"]
    if isinstance(default, int):
        lo = -(10**6) if low is None else low
        hi = 10**6 if high is None else high
        valid = st.integers(lo, hi).flatmap(lambda n: st.sampled_from(_int_kinds(n)))
        outside = st.one_of(
            st.integers(max_value=lo - 1) if low is not None else st.nothing(),
            st.integers(min_value=hi + 1) if high is not None else st.nothing(),
            st.sampled_from([10**400, -(10**400)]),
        ).flatmap(lambda n: st.sampled_from(_int_kinds(n)))
        not_int = st.one_of(
            st.floats(),  # even a whole float: an int field takes ints only
            st.integers(lo, hi).map(float),
            st.booleans(),
            st.sampled_from([np.True_, np.float64(lo), np.float32(hi), str(lo), None]),
            junk().filter(lambda v: not (isinstance(v, (int, np.integer)) and not _is_bool(v))),
        )
        return st.one_of(
            valid.map(lambda v: (v, True)),
            outside.map(lambda v: (v, False)),
            not_int.map(lambda v: (v, False)),
        )
    assert isinstance(default, float), f"{field.name}: no strategy for {type(default)}"
    floats = st.floats(low, high, allow_nan=False)
    as_kinds = floats.flatmap(
        lambda x: st.sampled_from([x, np.float64(x), np.float32(x), np.float16(x)])
    )
    int_low = math.ceil(low) if low is not None else -(10**6)
    int_high = math.floor(high) if high is not None else 10**6
    ints = (
        st.integers(int_low, int_high).flatmap(lambda n: st.sampled_from(_int_kinds(n)))
        if int_low <= int_high
        else st.nothing()
    )
    outside = st.one_of(
        st.floats(max_value=low, exclude_max=True) if low is not None else st.nothing(),
        st.floats(min_value=high, exclude_min=True) if high is not None else st.nothing(),
        special_floats(),
        st.sampled_from([10**400, -(10**400)]),
    )
    wrong_type = st.one_of(
        st.booleans(),
        st.complex_numbers(),
        st.sampled_from([None, str(default), [default], np.array([default]), np.True_]),
        junk().filter(lambda v: not _is_real(v)),
    )
    return st.one_of(
        # a float32 or float16 may round out of the range: valid only if it did not
        as_kinds.map(lambda v: (v, _finite_in_range(v, meta))),
        ints.map(lambda v: (v, _finite_in_range(v, meta))),
        outside.map(lambda v: (v, _finite_in_range(v, meta))),  # -0.0 is in [0, ...]
        wrong_type.map(lambda v: (v, False)),
    )


def _is_bool(value: Any) -> bool:
    return isinstance(value, (bool, np.bool_))


def _is_real(value: Any) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not _is_bool(value)


def _finite_in_range(value: Any, meta: dict) -> bool:
    try:
        number = float(value)
    except OverflowError:
        return False
    return math.isfinite(number) and _in_range(number, meta)


def _is_choice(value: Any, choices) -> bool:
    return isinstance(value, str) and value in choices


# --- actions ----------------------------------------------------------------------------
VALID, INVALID = True, False


def actions(shape: tuple[int, ...]) -> st.SearchStrategy:
    """(action, valid) pairs for an action space of ``shape``: valid ones are finite real
    numbers (Python's or any NumPy int or float dtype, any size: they are clipped) of the
    right shape; the rest is junk."""
    n = shape[0]
    finite = st.floats(allow_nan=False, allow_infinity=False)
    real_dtypes = [d for d in NUMERIC_DTYPES]
    valid = st.one_of(
        st.lists(finite, min_size=n, max_size=n),
        st.tuples(*[finite] * n),
        st.lists(st.integers(-(2**63), 2**63 - 1), min_size=n, max_size=n),
        st.sampled_from(real_dtypes).flatmap(
            lambda dtype: hnp.arrays(
                np.dtype(dtype),
                shape,
                elements=hnp.from_dtype(np.dtype(dtype), allow_nan=False, allow_infinity=False),
            )
        ),
        st.lists(
            st.sampled_from([np.float32, np.float64, np.int64, np.uint8]).map(lambda t: t(1)),
            min_size=n,
            max_size=n,
        ),
    )
    non_finite = st.tuples(
        st.lists(finite, min_size=n, max_size=n),
        st.integers(0, n - 1),
        st.sampled_from([math.nan, math.inf, -math.inf]),
        st.sampled_from([list, np.float64, np.float32, np.float16]),
    ).map(_with_bad_entry)
    wrong_shape = st.one_of(
        st.lists(finite, max_size=6).filter(lambda v: len(v) != n),
        hnp.arrays(np.float64, hnp.array_shapes(min_dims=0, max_dims=3)).filter(
            lambda a: a.shape != shape
        ),
        st.lists(st.lists(finite, min_size=1, max_size=3), min_size=n, max_size=n),  # ragged
        finite,
    )
    not_real = st.one_of(
        numpy_arrays(shape, ODD_DTYPES),
        st.lists(st.complex_numbers(), min_size=n, max_size=n).filter(
            lambda v: any(isinstance(c, complex) for c in v)
        ),
        st.lists(st.text(max_size=3), min_size=n, max_size=n),
        st.lists(st.none(), min_size=n, max_size=n),
        st.lists(finite, min_size=n, max_size=n).map(lambda v: np.ma.masked_array(v)),
        st.lists(finite, min_size=n, max_size=n).map(lambda v: np.array(v, dtype=object)),
        st.lists(st.sampled_from([10**400, -(10**400)]), min_size=n, max_size=n),
        st.lists(st.booleans(), min_size=n, max_size=n),
        junk().filter(lambda v: not _maybe_valid_action(v, shape)),
    )
    return st.one_of(
        valid.map(lambda v: (v, VALID)),
        non_finite.map(lambda v: (v, INVALID)),
        wrong_shape.map(lambda v: (v, INVALID)),
        not_real.map(lambda v: (v, INVALID)),
    )


def _with_bad_entry(args) -> Any:
    values, index, bad, kind = args
    values = list(values)
    values[index] = bad
    if kind is list:
        return values
    with np.errstate(over="ignore"):  # big finite floats overflow to inf: still non-finite
        return np.array(values, dtype=kind)


def _maybe_valid_action(value: Any, shape) -> bool:
    """Whether junk might happen to be a valid action (then it is left out of the junk)."""
    try:
        array = np.asarray(value)
    except Exception:
        return False
    return array.shape == shape and array.dtype.kind in "iuf"
