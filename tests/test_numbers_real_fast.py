"""``protocol.numbers.real_number`` takes a plain float at once (the board emulator asks it ~15 000 times
a run: its rates, widths and the dead-ESC thresholds); whatever takes that path gives what the general
path gives, bit for bit, and a float's subclass, numpy's scalars and 0-d arrays still take the general
path to a plain float."""

from __future__ import annotations

import struct

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from protocol.numbers import real_number


def general(value: object) -> float | None:
    """The general path (what the function did before its fast path): numbers.Real, bool refused."""
    import math
    import numbers

    if getattr(value, "shape", None) == () and hasattr(value, "item"):
        value = value.item()
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        return None
    try:
        return float(value)
    except OverflowError:
        return math.inf if value > 0 else -math.inf  # type: ignore[operator]


def bits(x: float | None) -> bytes | None:
    return None if x is None else struct.pack("<d", x)


class Seconds(float):
    """A float subclass, as a user's unit type might be."""


@given(st.floats(allow_nan=True, allow_infinity=True, allow_subnormal=True))
def test_a_float_is_itself_as_the_general_path_gives_it(x: float) -> None:
    assert bits(real_number(x)) == bits(general(x))
    assert type(real_number(x)) is float


@given(st.floats(allow_nan=True, allow_infinity=True))
def test_a_float_subclass_and_numpy_scalars_give_a_plain_float(x: float) -> None:
    with np.errstate(over="ignore"):  # a float beyond float32's range is its inf
        narrow = np.float32(x)
    for value in (Seconds(x), np.float64(x), narrow, np.array(x)):
        got = real_number(value)
        assert type(got) is float
        assert bits(got) == bits(general(value))


def test_what_is_no_real_number_is_still_refused() -> None:
    for value in (True, np.bool_(False), "1.5", None, 1 + 2j, [1.0]):
        assert real_number(value) is None
