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
    """``x`` rounded to the nearest IEEE-754 binary32 (what the binary format stores)."""
    value: float = _F32.unpack(_F32.pack(x))[0]
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
    if not math.isfinite(x) or abs(x) > F32_MAX:
        raise CalibrationError(f"{value!r} is not a finite float32", where)
    return f32(x)


def require_finite(value: float, what: str, name: str) -> float:
    """``value`` as a float, or :class:`FieldRangeError` naming ``what.name`` if it is NaN or infinite."""
    x = float(value)
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
