"""What the world's phone does wrong on purpose (``firmware-sim --phone-jump``, ``--phone-spoof``; a fault
campaign's phone kinds): its clock jumps, and it sends hostile readings — values that parse but are
absurd, or plausible values stamped at the wrong time. Applied to the samples the world hands out
(:meth:`firmware_sim.world.World.advance_to`), so they reach the host the way the phone's samples do: in
process in lockstep, over UDP from ``firmware-sim --world``.

The board's :class:`~firmware_sim.board.faults.FaultInjector` holds the schedule (board-clock times); this
module keeps what applying it needs (the spoofs already sent, the last plausible reading of each sensor).
"""

from __future__ import annotations

import math
from dataclasses import replace

from hil.estimation.sensors import KINDS, SensorKind, SensorSample

from ..board.faults import FaultInjector, PhoneSpoof

HUGE = 1e160
SATURATED = {SensorKind.GYR: 1e6, SensorKind.ACC: 1e5, SensorKind.MAG: 1e7}  # rad/s, m/s², µT
SPOOF_SHIFT_S = 100.0  # a future / past reading's stamp, from the phone's newest
BURST = 200  # readings in a burst, all within BURST_SPAN_S
BURST_SPAN_S = 1e-3


class PhoneTamper:
    """Applies ``faults``' phone jumps and spoofs to the world's samples, in order."""

    def __init__(self, faults: FaultInjector) -> None:
        self.faults = faults
        self._spoofs_sent = 0
        self._last: dict[SensorKind, SensorSample] = {}
        self.sent = 0  # hostile readings sent so far

    @property
    def active(self) -> bool:
        return bool(self.faults.phone_jumps or self.faults.phone_spoofs)

    def apply(self, samples: list[SensorSample], now: float) -> list[SensorSample]:
        """``samples`` (taken up to board time ``now``) as the faulty phone sends them: each stamp moved by
        the clock jumps made before it was taken, and the spoofs due by ``now`` added after them."""
        faults = self.faults
        out = samples
        if faults.phone_jumps:
            out = [_shifted(s, faults.phone_offset(s.t_s)) for s in samples]
        for s in out:
            if math.isfinite(s.t_s):
                self._last[s.kind] = s
        spoofs = faults.phone_spoofs
        while self._spoofs_sent < len(spoofs) and spoofs[self._spoofs_sent].at <= now:
            hostile = self._hostile(spoofs[self._spoofs_sent], now + faults.phone_offset(now))
            self.sent += len(hostile)
            out = out + hostile
            self._spoofs_sent += 1
        return out

    def _hostile(self, spoof: PhoneSpoof, stamp: float) -> list[SensorSample]:
        """The readings of one spoof, stamped around ``stamp`` (the phone's clock now)."""
        last = [self._last.get(k, SensorSample(stamp, k, (0.0, 0.0, 1.0))) for k in KINDS]
        kind = spoof.kind
        if kind == "huge":
            return [SensorSample(stamp, s.kind, (HUGE, -HUGE, HUGE)) for s in last]
        if kind == "nan":
            return [SensorSample(stamp, s.kind, (math.nan, math.nan, math.nan)) for s in last]
        if kind == "saturated":
            return [SensorSample(stamp, s.kind, (SATURATED[s.kind], 0.0, 0.0)) for s in last]
        if kind == "future":
            return [replace(s, t_s=stamp + SPOOF_SHIFT_S) for s in last]
        if kind == "past":
            return [replace(s, t_s=stamp - SPOOF_SHIFT_S) for s in last]
        if kind == "duplicate":
            return list(last)
        assert kind == "burst", kind
        gyr, acc = last[0], last[1]
        step = BURST_SPAN_S / BURST
        return [replace(gyr if i % 2 == 0 else acc, t_s=stamp + i * step) for i in range(BURST)]


def _shifted(sample: SensorSample, offset: float) -> SensorSample:
    return sample if offset == 0.0 else replace(sample, t_s=sample.t_s + offset)
