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

from .errors import ConfigError, FieldRangeError, value_repr
from .messages import MAX_CHANNELS, PULSE_MAX_US
from .numbers import real_number, whole_number

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
    :class:`FieldRangeError` if it is no number (a bool: ``True`` was a 1 µs pulse), not finite (10**400
    was an ``OverflowError``) or outside 0..PULSE_MAX_US."""
    width = real_number(width_us)
    if width is None or not (math.isfinite(width) and 0.0 <= width <= PULSE_MAX_US):
        raise FieldRangeError("fine_width", "width_us", width_us)
    return round(width * FINE_PER_US)


def whole_us(width_us: int) -> int:
    """A whole-µs width (the safe pulse, raw pulses, an ESC endpoint) as a fine width: exact ticks.
    :class:`FieldRangeError` unless it is an integer (not a bool) in 0..PULSE_MAX_US: 1.5 made a float
    "fine width" that the dither then refused with a raw ``TypeError``, -5 a negative width."""
    if not _is_integer_in(width_us, PULSE_MAX_US):
        raise FieldRangeError("whole_us", "width_us", width_us)
    return int(width_us) * FINE_PER_US


def reported_us(fine: int) -> int:
    """The whole µs a fine width is reported as (half up): ``(fine + 256) >> 9``. :class:`FieldRangeError`
    unless ``fine`` is a fine width (an integer in 0..FINE_MAX): -1 was reported as 0 µs, no pulse."""
    if not _is_integer_in(fine, FINE_MAX):
        raise FieldRangeError("reported_us", "fine", fine)
    return (int(fine) + FINE_PER_US // 2) // FINE_PER_US


def _is_integer_in(value: object, top: int) -> bool:
    """Whether ``value`` is an integer (numpy's too, not a bool) in ``0..top``."""
    whole = whole_number(value)
    return whole is not None and 0 <= whole <= top


class SigmaDelta:
    """The dither of ``channels`` outputs: :meth:`frame` turns the fine widths of one frame into the
    widths (µs, whole ticks) the timers put out, carrying each channel's remainder (256ths of a tick) to
    the next frame. A channel without a pulse (None or 0) keeps its remainder. :meth:`reset` is the MCU
    reset (the remainders start at 0)."""

    def __init__(self, channels: int) -> None:
        count = whole_number(channels)
        if count is None or not 1 <= count <= MAX_CHANNELS:
            raise ConfigError(
                f"{value_repr(channels)} must be an integer in 1..{MAX_CHANNELS}", "SigmaDelta.channels"
            )
        self.residue: list[int] = [0] * count

    def reset(self) -> None:
        self.residue = [0] * len(self.residue)

    def frame(self, fine: Sequence[int | None]) -> tuple[float | None, ...]:
        """One frame's widths (µs, multiples of :data:`TICK_US`; None: no pulse) for the fine widths, one
        per channel (fewer: the rest carry no pulse). :class:`FieldRangeError` naming the channel for a
        width that is not a fine width (an integer in 0..FINE_MAX, not a bool) or for more widths than
        channels — before any remainder moves, so a refused frame leaves the dither as it was. (More
        widths were an ``IndexError``, a float one a ``TypeError``, a negative one a negative width.)"""
        if len(fine) > len(self.residue):
            raise FieldRangeError(
                "SigmaDelta.frame", "fine", f"{len(fine)} widths for {len(self.residue)} channels"
            )
        for ch, q in enumerate(fine):
            if q is not None and not _is_integer_in(q, FINE_MAX):
                raise FieldRangeError("SigmaDelta.frame", f"fine[{ch}]", q)
        out: list[float | None] = []
        residue = self.residue
        for ch, q in enumerate(fine):
            if not q:
                out.append(None)
                continue
            q = int(q)  # numpy's integer as the int it is: the remainders stay Python ints
            s = residue[ch] + (q & _FRACTION)
            residue[ch] = s & _FRACTION
            out.append(((q >> FRACTION_BITS) + (s >> FRACTION_BITS)) * TICK_US)
        return tuple(out)
