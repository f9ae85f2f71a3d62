"""What counts as a number where the protocol takes one from its caller: a pulse width, an edge time, a
clock's ``now``, a retry policy's timeout, a message's float field."""

from __future__ import annotations

import math
import numbers


def real_number(value: object) -> float | None:
    """``value`` as a float if it is a real number — an int, a float, numpy's scalars or a 0-d array of
    one — else None: a bool (a flag, not a time or a width), a string, None. An integer beyond a float's
    range (10**400) is ±inf, as far as a float can say, not the ``OverflowError`` ``float()`` raises;
    NaN stays NaN. The one test of "is this a number" for the protocol's entry points (the pulse
    modules, the reliable layer's times and policy, a message's float fields): a width, a time or a rate
    that is not one got a raw ``TypeError``/``OverflowError`` out of them, or was taken as a number
    (``True`` as 1 µs, the string ``"1500"`` as an edge time)."""
    if type(value) is float:  # the hot path: the board's every rate, width and threshold (a subclass: below)
        return value
    if getattr(value, "shape", None) == () and hasattr(value, "item"):
        value = value.item()  # a 0-d array: the number (or bool) it holds
    if isinstance(value, bool) or not isinstance(value, numbers.Real):  # numpy's bool is no Real
        return None
    try:
        return float(value)
    except OverflowError:  # only an integer is past a float's range
        return math.inf if value > 0 else -math.inf  # type: ignore[operator]  # a Real compares with 0


def whole_number(value: object) -> int | None:
    """``value`` as an int if it is an integer — a Python int, numpy's integer scalars or a 0-d integer
    array — else None: a bool (a flag, not a count), a float (even 3.0: a whole-number field takes no
    float's rounding), a string, None. The one test of "is this an integer" for a message's integer and
    enum fields and the pulse modules' integer widths: numpy's ``uint16(3)``, what an array-built
    controller hands over, was refused as "out of range"."""
    if type(value) is int:  # the hot path: every pulse width of the board's outputs, every int field
        return value
    if getattr(value, "shape", None) == () and hasattr(value, "item"):
        value = value.item()  # a 0-d array: the integer (or bool, or float) it holds
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):  # numpy's bool is no Integral
        return None
    return int(value)
