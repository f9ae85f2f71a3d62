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
``unplug(duration, at=)``     the board's USB cable is pulled for ``duration`` s: the MCU loses power
                              (held in reset, no pulses, nothing sent) and, in process, the port
                              vanishes; plugged back, it boots with reset cause POWER_ON (what a
                              ``firmware-sim`` killed and started again looks like to the host)
``noisy_link(p, duration, at=)``  byte corruption at probability ``p`` per byte, both ways, for
                              ``duration`` s (a noisy cable for a while)
``phone_jump(offset, at=)``   from ``at`` on, the world's phone stamps its samples ``offset`` s later
                              (negative: earlier) than before — an app restarted, a clock stepped
``phone_spoof(kind, at=)``    at ``at`` the world's phone sends a few hostile readings of ``kind``
                              (:data:`SPOOF_KINDS`): absurd values that still parse, or plausible
                              values with the wrong time
============================  ===================================================================
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass

from hil.timing.clock import Clock
from protocol.errors import ConfigError

DIRECTIONS = ("rx", "tx", "both")
SPOOF_KINDS = ("huge", "nan", "saturated", "future", "past", "duplicate", "burst")
"""Hostile readings the world's phone can send (:meth:`FaultInjector.phone_spoof`): ``huge`` (±1e160 in
every axis), ``nan``, ``saturated`` (a gyro reading of 1e6 rad/s), ``future`` / ``past`` (a plausible
triple stamped 100 s ahead / behind), ``duplicate`` (the last triple again, same times), ``burst`` (200
plausible readings stamped within one millisecond)."""


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


@dataclass(frozen=True)
class PhoneJump:
    """From board time ``at`` on, the phone's stamps are ``offset_s`` later (negative: earlier)."""

    at: float
    offset_s: float


@dataclass(frozen=True)
class PhoneSpoof:
    """Hostile readings of ``kind`` (:data:`SPOOF_KINDS`) sent at board time ``at``."""

    at: float
    kind: str


@dataclass(frozen=True)
class NoiseWindow:
    """Byte corruption at ``corrupt`` per byte, both ways, over ``[start, start + duration)``."""

    start: float
    duration: float
    corrupt: float

    def covers(self, t: float) -> bool:
        return self.start <= t < self.start + self.duration


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
        self.unplugs: list[Stall] = []
        self.noise_windows: list[NoiseWindow] = []
        self.phone_jumps: list[PhoneJump] = []
        self.phone_spoofs: list[PhoneSpoof] = []
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

    def unplug(self, duration: float, at: float | None = None) -> Stall:
        """Pull the board's USB cable at ``at`` for ``duration`` s (see the module docstring)."""
        _check_positive(duration, "faults.unplug.duration")
        u = Stall(self._at(at), float(duration))
        self.unplugs.append(u)
        self.unplugs.sort(key=lambda x: x.start)
        return u

    def noisy_link(self, corrupt: float, duration: float, at: float | None = None) -> NoiseWindow:
        """Corrupt bytes at probability ``corrupt`` per byte, both ways, from ``at`` for ``duration`` s."""
        if not (isinstance(corrupt, (int, float)) and 0.0 <= corrupt <= 1.0):
            raise ConfigError(f"{corrupt!r} is not a probability in 0..1", "faults.noise.corrupt")
        _check_nonneg(duration, "faults.noise.duration")
        w = NoiseWindow(self._at(at), float(duration), float(corrupt))
        self.noise_windows.append(w)
        return w

    def phone_jump(self, offset_s: float, at: float | None = None) -> PhoneJump:
        """From ``at`` on, stamp the world's phone samples ``offset_s`` s later (negative: earlier)."""
        if not (isinstance(offset_s, (int, float)) and math.isfinite(offset_s) and offset_s != 0):
            raise ConfigError(
                f"{offset_s!r} must be a finite, non-zero number of seconds", "faults.phone_jump"
            )
        j = PhoneJump(self._at(at), float(offset_s))
        self.phone_jumps.append(j)
        self.phone_jumps.sort(key=lambda x: x.at)
        return j

    def phone_spoof(self, kind: str, at: float | None = None) -> PhoneSpoof:
        """Send hostile readings of ``kind`` (:data:`SPOOF_KINDS`) from the world's phone at ``at``."""
        if kind not in SPOOF_KINDS:
            raise ConfigError(f"{kind!r} is not one of {', '.join(SPOOF_KINDS)}", "faults.phone_spoof")
        sp = PhoneSpoof(self._at(at), kind)
        self.phone_spoofs.append(sp)
        self.phone_spoofs.sort(key=lambda x: x.at)
        return sp

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
        self.unplugs.clear()
        self.noise_windows.clear()
        self.phone_jumps.clear()
        self.phone_spoofs.clear()

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

    def unplugged(self, t: float) -> Stall | None:
        """The unplug in effect at ``t`` (the cable out, the board unpowered), if any."""
        for u in self.unplugs:
            if u.covers(t):
                return u
        return None

    def next_unplug(self, t: float) -> float:
        """When the next unplug at or after ``t`` starts (inf: none)."""
        return next((u.start for u in self.unplugs if u.start >= t), math.inf)

    def phone_offset(self, t: float) -> float:
        """How far the phone's clock is off at board time ``t`` (s): the jumps up to then, summed."""
        return sum(j.offset_s for j in self.phone_jumps if j.at <= t)

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
        if self.noise_windows:
            window = next((w for w in self.noise_windows if w.covers(t)), None)
            if window is not None and window.corrupt > noise.corrupt:
                noise = LinkNoise(window.corrupt, noise.drop, "both")
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


def _check_positive(value: float, where: str) -> None:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise ConfigError(f"{value!r} must be a finite number > 0", where)
