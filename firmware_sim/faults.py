"""Fault injection: what can go wrong with the link, the MCU, the battery and the ESCs.

All times are on the board's clock (seconds); ``at=None`` means now. The same faults are reachable from
the API (``board.faults.hang()``) and the command line (``firmware-sim --hang-at 5``, see
:func:`parse_fault_args`). Random link damage is seeded, so a run replays exactly.

============================  ===================================================================
fault                         effect
============================  ===================================================================
``link(corrupt=, drop=)``     each byte on the link is damaged (random bits flipped) or lost with
                              these probabilities; ``direction`` "rx" (host→board), "tx" or "both"
``stall(duration, at=)``      the link carries nothing for ``duration`` s (a pulled cable)
``hang(at=)``                 the main loop stops (pulse timers keep their last widths); the MCU
                              watchdog resets the board ``mcu_watchdog_s`` later
``sag(drop_v, …, at=)``       the pack's open-circuit voltage drops by ``drop_v`` (ramped over
                              ``ramp_s``) and/or its resistance grows by ``extra_resistance_ohm``
``dead_esc(channel, at=)``    the ESC/servo on that output channel stops responding
``phone_gap(duration, at=)``  the world's simulated phone sends nothing for ``duration`` s (an app
                              that pauses its stream and resumes it; only with a world)
============================  ===================================================================
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass

from hil.timing.clock import Clock
from protocol.errors import ConfigError

DIRECTIONS = ("rx", "tx", "both")


@dataclass(frozen=True)
class LinkNoise:
    corrupt: float = 0.0  # probability per byte of flipped bits
    drop: float = 0.0  # probability per byte of losing it
    direction: str = "both"


@dataclass(frozen=True)
class Stall:
    start: float
    duration: float

    def covers(self, t: float) -> bool:
        return self.start <= t < self.start + self.duration


@dataclass(frozen=True)
class Sag:
    start: float
    drop_v: float = 0.0
    extra_resistance_ohm: float = 0.0
    ramp_s: float = 0.0
    duration: float = math.inf

    def level(self, t: float) -> float:
        """Fraction (0..1) of the sag in effect at ``t``."""
        if t < self.start or t >= self.start + self.duration:
            return 0.0
        if self.ramp_s <= 0.0:
            return 1.0
        return min((t - self.start) / self.ramp_s, 1.0)


@dataclass
class LinkStats:
    corrupted: int = 0
    dropped: int = 0
    stalled: int = 0


class FaultInjector:
    """Holds the active and scheduled faults of one board. ``clock`` gives "now" for ``at=None``;
    ``n_channels`` bounds the channels a dead ESC may be on (None: not checked)."""

    def __init__(self, clock: Clock, seed: int = 0, n_channels: int | None = None) -> None:
        self._clock = clock
        self.n_channels = n_channels
        self._rng = random.Random(seed)
        self.noise = LinkNoise()
        self.stalls: list[Stall] = []
        self.hangs: list[float] = []  # pending hang times
        self.sags: list[Sag] = []
        self.dead_escs: dict[int, float] = {}  # channel -> from when
        self.phone_gaps: list[Stall] = []
        self.stats = LinkStats()

    # ------------------------------------------------------------------ API
    def link(self, corrupt: float = 0.0, drop: float = 0.0, direction: str = "both") -> None:
        """Set random link damage (probabilities per byte)."""
        for name, p in (("corrupt", corrupt), ("drop", drop)):
            if not (isinstance(p, (int, float)) and 0.0 <= p <= 1.0):
                raise ConfigError(f"{p!r} is not a probability in 0..1", f"faults.link.{name}")
        if direction not in DIRECTIONS:
            raise ConfigError(f"{direction!r} is not one of {', '.join(DIRECTIONS)}", "faults.link.direction")
        self.noise = LinkNoise(float(corrupt), float(drop), direction)

    def stall(self, duration: float, at: float | None = None) -> Stall:
        _check_nonneg(duration, "faults.stall.duration")
        s = Stall(self._at(at), float(duration))
        self.stalls.append(s)
        return s

    def hang(self, at: float | None = None) -> float:
        """Hang the main loop at ``at`` (s; None: now). A hang due while the MCU is in reset or booting
        waits: it takes the main loop the first time that runs."""
        t = self._at(at)
        self.hangs.append(t)
        self.hangs.sort()
        return t

    def sag(
        self,
        drop_v: float = 0.0,
        extra_resistance_ohm: float = 0.0,
        ramp_s: float = 0.0,
        at: float | None = None,
        duration: float = math.inf,
    ) -> Sag:
        _check_nonneg(drop_v, "faults.sag.drop_v")
        _check_nonneg(extra_resistance_ohm, "faults.sag.extra_resistance_ohm")
        _check_nonneg(ramp_s, "faults.sag.ramp_s")
        if not duration > 0:
            raise ConfigError(f"{duration!r} must be > 0", "faults.sag.duration")
        s = Sag(self._at(at), float(drop_v), float(extra_resistance_ohm), float(ramp_s), float(duration))
        self.sags.append(s)
        return s

    def phone_gap(self, duration: float, at: float | None = None) -> Stall:
        """The world's phone sends nothing from ``at`` for ``duration`` s (its samples are not taken)."""
        _check_nonneg(duration, "faults.phone_gap.duration")
        gap = Stall(self._at(at), float(duration))
        self.phone_gaps.append(gap)
        return gap

    def dead_esc(self, channel: int, at: float | None = None) -> None:
        where = "faults.dead_esc.channel"
        if isinstance(channel, bool) or not isinstance(channel, int) or channel < 0:
            raise ConfigError(f"{channel!r} is not an output channel number", where)
        if self.n_channels is not None and channel >= self.n_channels:
            raise ConfigError(f"channel {channel} does not exist (the board has {self.n_channels})", where)
        self.dead_escs[channel] = self._at(at)

    def clear(self) -> None:
        """Remove every fault (pending hangs included); counters are kept."""
        self.noise = LinkNoise()
        self.stalls.clear()
        self.hangs.clear()
        self.sags.clear()
        self.dead_escs.clear()
        self.phone_gaps.clear()

    # ------------------------------------------------------------------ used by the board
    def next_hang(self) -> float:
        return self.hangs[0] if self.hangs else math.inf

    def pop_hang(self) -> float:
        return self.hangs.pop(0)

    def battery_sag(self, t: float) -> tuple[float, float]:
        """(volts, ohms) of sag in effect at ``t``."""
        volts = ohms = 0.0
        for s in self.sags:
            k = s.level(t)
            volts += k * s.drop_v
            ohms += k * s.extra_resistance_ohm
        return volts, ohms

    def phone_silent(self, t: float) -> bool:
        """Whether the world's phone is paused at ``t``."""
        return any(g.covers(t) for g in self.phone_gaps)

    def channel_dead(self, channel: int, t: float) -> bool:
        since = self.dead_escs.get(channel)
        return since is not None and t >= since

    def filter(self, data: bytes, t: float, direction: str) -> bytes:
        """``data`` as it crosses the link at ``t`` in ``direction`` ("rx" or "tx")."""
        if not data:
            return data
        if self.stalls and any(s.covers(t) for s in self.stalls):  # (no generator for no stalls)
            self.stats.stalled += len(data)
            return b""
        noise = self.noise
        if noise.direction not in (direction, "both") or (noise.corrupt == 0.0 and noise.drop == 0.0):
            return data
        rng = self._rng
        out = bytearray()
        for b in data:
            if noise.drop and rng.random() < noise.drop:
                self.stats.dropped += 1
                continue
            if noise.corrupt and rng.random() < noise.corrupt:
                b ^= rng.randrange(1, 256)
                self.stats.corrupted += 1
            out.append(b)
        return bytes(out)

    def _at(self, at: float | None) -> float:
        if at is None:
            return self._clock.now()
        if not (isinstance(at, (int, float)) and math.isfinite(at)):
            raise ConfigError(f"{at!r} is not a time in seconds", "faults.at")
        return float(at)


def _check_nonneg(value: float, where: str) -> None:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
        raise ConfigError(f"{value!r} must be a finite number >= 0", where)
