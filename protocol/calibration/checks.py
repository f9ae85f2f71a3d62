"""Checks shared by the calibration modules: float32 rounding, finiteness, and error locations."""

from __future__ import annotations

import math
import struct
from collections.abc import Iterator
from contextlib import contextmanager

from ..errors import CalibrationError, FieldRangeError, value_repr
from ..numbers import real_number

_F32 = struct.Struct("<f")
F32_MAX = 3.4028234663852886e38


def f32(x: float) -> float:
    """``x`` rounded to the nearest IEEE-754 binary32 (what the binary format stores, and what a float32
    operation of float32 operands yields when ``x`` is the exact or double result): beyond float32's range,
    ±inf, as in C (``struct`` raises ``OverflowError`` there instead)."""
    try:
        value: float = _F32.unpack(_F32.pack(x))[0]
    except OverflowError:
        return math.copysign(math.inf, x)
    return value


def finite32(value: object, where: str) -> float:
    """``value`` as a float32-exact float, or :class:`CalibrationError` at ``where`` if it is not a
    finite real number (:func:`~protocol.numbers.real_number`: no bool, no string) representable as
    float32. A string such as ``"1000"`` was taken as a number by ``float()``."""
    x = real_number(value)
    if x is None:
        raise CalibrationError(f"{value_repr(value)} is not a number", where)
    if not math.isfinite(x) or abs(x) > F32_MAX:
        raise CalibrationError(f"{value_repr(value)} is not a finite float32", where)
    return f32(x)


def require_finite(value: object, what: str, name: str) -> float:
    """``value`` as a float, or :class:`FieldRangeError` naming ``what.name`` if it is not a finite real
    number (:func:`~protocol.numbers.real_number`, the protocol's one test of what a number is): NaN,
    ±inf, an integer beyond a float's range (10**400), a bool, a string, None. ``float()`` took
    ``"1500"`` as a 1500 µs pulse, ``True`` as a 1 rad/s gimbal rate and ``b"1"`` as 1, and raised a bare
    ``TypeError`` for None."""
    x = real_number(value)
    if x is None or not math.isfinite(x):
        raise FieldRangeError(what, name, value)
    return x


@contextmanager
def within(prefix: str) -> Iterator[None]:
    """Re-raise a :class:`CalibrationError` from the block with ``prefix`` in front of its ``where``."""
    try:
        yield
    except CalibrationError as exc:
        where = f"{prefix}.{exc.where}" if exc.where else prefix
        raise CalibrationError(exc.detail, where) from exc
