"""The emulated rotor ESC's endpoint programming: what a typical hobby ESC does with the pulses it sees
when it is powered up (factory endpoints, the high/low programming procedure, arming at minimum).

An ESC leaves the factory with endpoints ``factory_low_us``..``factory_high_us`` (:class:`EscParams`) and
keeps what it was taught across power cycles (its own EEPROM). What it does depends on the first pulse
it sees after power-up:

* at or below its arming threshold (``low + arm_fraction·span``): it **arms**: from then on its throttle
  follows the pulse between its endpoints;
* at or above ``low + program_fraction·span``: it enters **programming**. A pulse held there for
  ``high_ack_s`` is accepted as the new high endpoint (a real ESC beeps); the ESC then waits for the pulse
  to fall at least ``min_span_us`` below it and stay (±``stable_us``) for ``low_ack_s``: that is the new
  low endpoint. Both are stored together and the ESC arms. A pulse that leaves the high band before
  ``high_ack_s``, lost pulses or a power cut before the low is accepted teach nothing;
* anywhere else: it waits, unarmed, for a pulse at its arming threshold (a stick not at zero never
  starts a motor).

:class:`EmulatedEsc` is driven with the pulse on its channel and its supply (:meth:`EmulatedEsc.update`,
board time in seconds, non-decreasing); :attr:`EmulatedEsc.programmed` records every endpoint pair it
stored. The board's unit model asks :meth:`EmulatedEsc.throttle_pulse` whether the motor is driven. The
conformance suite replays the same model over the pulses the C firmware puts on its pins.
"""

from __future__ import annotations

import enum
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple


class EscMode(enum.Enum):
    """What the ESC is doing."""

    OFF = "off"  # no supply
    STARTING = "starting"  # powered, no pulse seen yet
    WAITING = "waiting"  # powered, waiting for a pulse at its arming threshold
    PROGRAM_HIGH = "program_high"  # powered up at full throttle: the acknowledgement interval runs
    PROGRAM_LOW = "program_low"  # high endpoint accepted: waiting for the low one
    ARMED = "armed"  # the motor follows the pulse


# Looked up once: an enum member's lookup costs about 60 ns, and every physics step asks each ESC.
_OFF, _ARMED = EscMode.OFF, EscMode.ARMED


@dataclass(frozen=True)
class EscParams:
    """A hobby ESC's programming behaviour. Pulses in µs, times in s."""

    factory_low_us: float = 1100.0
    factory_high_us: float = 1900.0
    arm_fraction: float = 0.05  # arms on a first pulse at or below low + this fraction of the span
    program_fraction: float = 0.75  # enters programming on a first pulse at or above this fraction
    high_ack_s: float = 1.0  # the high pulse held this long is accepted
    low_ack_s: float = 0.5  # the low pulse held this long (within ±stable_us) is accepted
    stable_us: float = 10.0
    min_span_us: float = 400.0  # a low endpoint must lie at least this far below the high one


class Programmed(NamedTuple):
    """Endpoints the ESC stored at ``t`` (s)."""

    t: float
    low_us: float
    high_us: float


@dataclass
class EmulatedEsc:
    """One rotor ESC; ``low_us``/``high_us`` are its present endpoints (factory until programmed)."""

    params: EscParams = field(default_factory=EscParams)
    mode: EscMode = EscMode.OFF
    low_us: float = field(init=False)
    high_us: float = field(init=False)
    programmed: list[Programmed] = field(default_factory=list)
    _since: float = 0.0
    _high_seen: float = 0.0
    _low_seen: float | None = None

    def __post_init__(self) -> None:
        self.low_us = self.params.factory_low_us
        self.high_us = self.params.factory_high_us

    @property
    def powered(self) -> bool:
        return self.mode is not _OFF

    def update(self, t: float, pulse_us: float | None, powered: bool) -> None:
        """The ESC at time ``t`` (s) with ``pulse_us`` on its input (None: no pulse) and its supply."""
        if not powered:
            self.mode = _OFF
            return
        if self.mode is _ARMED:
            return  # the usual case, at every physics step: the motor follows the pulse, nothing changes
        if self.mode is _OFF:
            self._enter(EscMode.STARTING, t)
        if pulse_us is None:
            if self.mode in (EscMode.PROGRAM_HIGH, EscMode.PROGRAM_LOW):
                self._enter(EscMode.WAITING, t)  # signal lost while programming: nothing is taught
            return
        getattr(self, f"_{self.mode.value}")(t, pulse_us)

    def throttle_pulse(self, pulse_us: float | None) -> float | None:
        """The pulse the motor runs on (None: the motor is not driven: off, unarmed or programming)."""
        return pulse_us if self.mode is _ARMED else None

    # ------------------------------------------------------------------ modes
    def _enter(self, mode: EscMode, t: float) -> None:
        self.mode = mode
        self._since = t

    def _threshold(self, fraction: float) -> float:
        return self.low_us + fraction * (self.high_us - self.low_us)

    def _starting(self, t: float, pulse_us: float) -> None:
        if pulse_us >= self._threshold(self.params.program_fraction):
            self._enter(EscMode.PROGRAM_HIGH, t)
            self._high_seen = pulse_us
        else:
            self._enter(EscMode.WAITING, t)
            self._waiting(t, pulse_us)

    def _waiting(self, t: float, pulse_us: float) -> None:
        if pulse_us <= self._threshold(self.params.arm_fraction):
            self._enter(EscMode.ARMED, t)

    def _program_high(self, t: float, pulse_us: float) -> None:
        p = self.params
        if pulse_us < self._threshold(p.program_fraction):
            self._enter(EscMode.WAITING, t)  # left the high band before the acknowledgement: normal start
            self._waiting(t, pulse_us)
            return
        self._high_seen = pulse_us
        if t - self._since >= p.high_ack_s:
            self._enter(EscMode.PROGRAM_LOW, t)
            self._low_seen = None

    def _program_low(self, t: float, pulse_us: float) -> None:
        p = self.params
        if pulse_us > self._high_seen - p.min_span_us:
            self._low_seen = None  # still (or again) near the high endpoint
            return
        if self._low_seen is None or abs(pulse_us - self._low_seen) > p.stable_us:
            self._low_seen, self._since = pulse_us, t
            return
        if t - self._since >= p.low_ack_s:
            self.low_us, self.high_us = pulse_us, self._high_seen
            self.programmed.append(Programmed(t, self.low_us, self.high_us))
            self._enter(EscMode.ARMED, t)


def replay_esc(
    frames: Iterable[Sequence[Any]],
    channel: int,
    supply_cut: Sequence[tuple[float, bool]] = (),
    params: EscParams | None = None,
    gap_s: float = 0.05,
) -> EmulatedEsc:
    """An ESC that saw the pulse frames ``(t, widths)`` on ``channel``, powered from the start except while
    ``supply_cut`` says so (``(t, cut)`` changes, oldest first); a gap of more than ``gap_s`` between
    frames is a time without pulses. This is how the conformance suite tells what the C firmware's pins
    taught an ESC."""
    esc = EmulatedEsc(params if params is not None else EscParams())
    changes = list(supply_cut)
    cut, k = False, 0
    last: float | None = None

    def supply_until(t: float) -> None:
        nonlocal cut, k
        while k < len(changes) and changes[k][0] <= t:
            cut = changes[k][1]
            esc.update(changes[k][0], None, not cut)
            k += 1

    for frame in frames:  # (t, widths[, state]): a PulseFrame or a plain pair
        t, widths = frame[0], frame[1]
        if last is not None and t - last > gap_s:
            supply_until(last + gap_s)
            esc.update(last + gap_s, None, not cut)
        supply_until(t)
        esc.update(t, widths[channel], not cut)
        last = t
    return esc
