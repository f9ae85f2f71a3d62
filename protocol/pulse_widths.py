"""A board's pulse widths below the microsecond, sans-IO: the fine widths its outputs aim at and the
per-frame widths its timers put out, sigma-delta dithered so that their mean is the fine width.

Why. The ATmega2560's 16-bit timers at prescaler 8 tick every 0.5 µs (:data:`TICK_US`), and a calibration
map asks for any width in between: a gimbal servo turns ~6·10⁻³ rad/s per µs just past its dead zone, so a
width rounded to the tick (let alone to the microsecond) is no command below ~3·10⁻³ rad/s, and a hold
that needs less limit-cycles around it. A servo or an ESC answers the mean of the widths it sees over its
own time constant (tens of ms, several frames), so the board dithers: each frame puts out whole ticks, and
the fraction of a tick the frame could not carry is carried to the next frame (first-order sigma-delta).
Over ``n`` frames the widths add up to ``n`` times the fine width to within one tick, whatever ``n``.

Units. A **fine width** is an integer in 1/512 µs (:data:`FINE_PER_US`): ``fine >> 8`` whole ticks and
``fine & 0xFF`` 256ths of a tick — what the C firmware keeps (``pulses_set(ch, fine)``), exact in integer
arithmetic on both targets. :func:`fine_width` turns a map's µs into it (round half to even, as C's
``lrintf``); :func:`reported_us` is the whole µs the wire's ``Telemetry.pulses_us`` carries (half up: the
mean width, not one frame's). 0 is "no pulse".
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from .errors import FieldRangeError
from .messages import PULSE_MAX_US

TICK_US = 0.5
"""One timer tick (µs): 16 MHz / prescaler 8."""
FRACTION_BITS = 8
"""Bits of a tick's fraction in a fine width (256ths of a tick)."""
FINE_PER_US = 2 << FRACTION_BITS  # 512
"""Fine-width units per µs."""
FINE_MAX = PULSE_MAX_US * FINE_PER_US
_FRACTION = (1 << FRACTION_BITS) - 1


def fine_width(width_us: float) -> int:
    """``width_us`` (a calibration map's float µs) as a fine width, 1/512 µs, rounded half to even;
    :class:`FieldRangeError` if it is not finite or outside 0..PULSE_MAX_US."""
    if not (math.isfinite(width_us) and 0.0 <= width_us <= PULSE_MAX_US):
        raise FieldRangeError("fine_width", "width_us", width_us)
    return round(width_us * FINE_PER_US)


def whole_us(width_us: int) -> int:
    """A whole-µs width (the safe pulse, raw pulses, an ESC endpoint) as a fine width: exact ticks."""
    return width_us * FINE_PER_US


def reported_us(fine: int) -> int:
    """The whole µs a fine width is reported as (half up): ``(fine + 256) >> 9``."""
    return (fine + FINE_PER_US // 2) // FINE_PER_US


class SigmaDelta:
    """The dither of ``channels`` outputs: :meth:`frame` turns the fine widths of one frame into the
    widths (µs, whole ticks) the timers put out, carrying each channel's remainder (256ths of a tick) to
    the next frame. A channel without a pulse (None or 0) keeps its remainder. :meth:`reset` is the MCU
    reset (the remainders start at 0)."""

    def __init__(self, channels: int) -> None:
        self.residue = [0] * channels

    def reset(self) -> None:
        self.residue = [0] * len(self.residue)

    def frame(self, fine: Sequence[int | None]) -> tuple[float | None, ...]:
        """One frame's widths (µs, multiples of :data:`TICK_US`; None: no pulse) for the fine widths."""
        out: list[float | None] = []
        residue = self.residue
        for ch, q in enumerate(fine):
            if not q:
                out.append(None)
                continue
            s = residue[ch] + (q & _FRACTION)
            residue[ch] = s & _FRACTION
            out.append(((q >> FRACTION_BITS) + (s >> FRACTION_BITS)) * TICK_US)
        return tuple(out)
