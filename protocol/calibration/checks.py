"""Checks shared by the calibration modules: float32 rounding, finiteness, and error locations."""

from __future__ import annotations

import math
import struct
from collections.abc import Iterator
from contextlib import contextmanager

from ..errors import CalibrationError, FieldRangeError

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
    finite number representable as float32."""
    if isinstance(value, bool):
        raise CalibrationError(f"{value!r} is not a number", where)
    try:
        x = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError) as exc:
        raise CalibrationError(f"{value!r} is not a number", where) from exc
    except OverflowError as exc:  # an integer beyond any float (10**400): repr refuses 4300+ digits
        raise CalibrationError("an integer beyond a float's range is not a finite float32", where) from exc
    if not math.isfinite(x) or abs(x) > F32_MAX:
        raise CalibrationError(f"{value!r} is not a finite float32", where)
    return f32(x)


def require_finite(value: float, what: str, name: str) -> float:
    """``value`` as a float, or :class:`FieldRangeError` naming ``what.name`` if it is NaN, infinite, or an
    integer beyond a float's range (which ``float()`` refuses with a bare ``OverflowError``; the error then
    carries it as ±inf, as far as a float goes, since ``repr`` of an integer past 4300 digits raises)."""
    try:
        x = float(value)
    except OverflowError as exc:
        raise FieldRangeError(what, name, math.inf if value > 0 else -math.inf) from exc
    if not math.isfinite(x):
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
