"""The battery voltage to the 10 mV step the board's pulse conversions are cached at (``round(v, 2)``),
asked at every power sample and pulse frame for a voltage that moves by millivolts a second."""

from __future__ import annotations

import math

_BAND_V = 0.0049
"""How far (V) from the last result a voltage may lie and still round to it: below the 5 mV half step by a
margin far above the doubles' rounding error at battery voltages (~10⁻¹⁵ V)."""


class TenMillivolts:
    """``round(v, 2)`` with the last result kept: a voltage within :data:`_BAND_V` of it rounds to it.

    Why that is exact: the last result ``r`` is the double nearest a two-decimal number ``D``; a ``v`` with
    ``|v − r| < 4.9 mV`` lies within 5 mV of ``D`` (less one rounding error), so ``D`` is the unique
    two-decimal number nearest to ``v`` and ``round(v, 2)`` is ``r`` again. CPython's ``round`` with
    ``ndigits`` goes through the decimal digits (~0.5 µs); this is two comparisons while the voltage stays
    in its band. NaN is in no band (``round`` gives NaN), nor is a result of zero (its sign is the
    voltage's)."""

    __slots__ = ("_value", "_low", "_high")

    def __init__(self) -> None:
        self._value = math.nan
        self._low = math.inf
        self._high = -math.inf

    def __call__(self, volts: float) -> float:
        """``round(volts, 2)`` (V)."""
        if self._low < volts < self._high:
            return self._value
        value = round(volts, 2)
        self._value = value
        if value == 0.0:  # ±0.0 follows the voltage's sign: no band
            self._low, self._high = math.inf, -math.inf
        else:
            self._low, self._high = value - _BAND_V, value + _BAND_V
        return value
