"""The result of every calibration map: a value and whether (and at which end) the input was clamped.

A map never raises for an input outside its range: a board must always produce *some* pulse. It clamps to
the nearest end of its range instead and says so, so the firmware can raise ``SETPOINT_CLAMPED`` and the
host can see its command was not honoured. Non-finite inputs are a caller bug and raise
:class:`~protocol.errors.FieldRangeError` (the wire's F32 range checks never let NaN through).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass


class Clamp(enum.IntEnum):
    """Where an input fell relative to its map's range. ``LOW``/``HIGH`` refer to the *input* axis."""

    NONE = 0  # inside the range: the value is exact
    LOW = 1  # below the range: clamped to its low end
    HIGH = 2  # above the range: clamped to its high end


@dataclass(frozen=True, slots=True)
class Conversion:
    """``value`` in the map's output unit (µs, rad/s, rad, or throttle 0..1); ``clamp`` says whether the
    input was outside the map's range and clamped (then ``value`` is the range's end)."""

    value: float
    clamp: Clamp = Clamp.NONE

    @property
    def saturated(self) -> bool:
        """True when the input was outside the map's range and was clamped to its nearest end."""
        return self.clamp is not Clamp.NONE
