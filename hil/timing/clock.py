"""Injected clocks. Every loop, watchdog and pulse generator takes one, so the same code runs in real time
or in lockstep (simulated time, as fast as the CPU allows).

``now()`` is seconds (float) on the clock's own monotonic time base. Loops schedule against absolute
deadlines (``t_next += period``) with ``sleep_until(t_next)``, never ``sleep(period)``, so that period
errors do not accumulate.
"""

from __future__ import annotations

import math
import threading
import time
from typing import Protocol

from protocol.errors import ConfigError


class Clock(Protocol):
    def now(self) -> float:
        """Current time, seconds."""
        ...

    def sleep_until(self, deadline: float) -> None:
        """Return once ``now() >= deadline`` (immediately if already past)."""
        ...


class WallClock:
    """Real time from ``time.monotonic``; ``sleep_until`` sleeps to an absolute deadline."""

    def __init__(self) -> None:
        self._t0 = time.monotonic()

    def now(self) -> float:
        return time.monotonic() - self._t0

    def sleep_until(self, deadline: float) -> None:
        _check_finite(deadline, "WallClock.sleep_until")
        while True:
            remaining = deadline - self.now()
            if remaining <= 0.0:
                return
            time.sleep(remaining)


class LockstepClock:
    """Simulated time that only moves when told to. ``sleep_until`` jumps to the deadline (single
    driver) — a lockstep loop owns the clock and advances it itself. Thread-safe reads."""

    def __init__(self, start: float = 0.0) -> None:
        _check_finite(start, "LockstepClock")
        self._t = float(start)
        self._lock = threading.Lock()

    def now(self) -> float:
        return self._t  # one attribute read: atomic, no lock needed (called tens of times per tick)

    def advance(self, dt: float) -> float:
        """Move time forward by ``dt`` ≥ 0 seconds; returns the new time."""
        _check_finite(dt, "LockstepClock.advance")
        if dt < 0:
            raise ConfigError(f"cannot move a clock backwards (dt={dt})", "LockstepClock.advance")
        with self._lock:
            self._t += dt
            return self._t

    def set(self, t: float) -> None:
        """Jump to ``t`` (not earlier than now)."""
        _check_finite(t, "LockstepClock.set")
        with self._lock:
            if t < self._t:
                raise ConfigError(f"cannot move a clock backwards ({t} < {self._t})", "LockstepClock.set")
            self._t = float(t)

    def sleep_until(self, deadline: float) -> None:
        _check_finite(deadline, "LockstepClock.sleep_until")
        with self._lock:
            if deadline > self._t:
                self._t = float(deadline)


def _check_finite(seconds: float, where: str) -> None:
    """Refuse a time that is not a finite number of seconds, naming ``where`` it came. A lockstep clock
    told NaN once kept it for ever (every comparison with it false: a run went on with every time stamp
    NaN), told ``inf`` (a wait with nothing to wake it) jumped past every deadline; the wall clock raised
    Python's own ``OverflowError`` / ``ValueError`` from ``time.sleep``."""
    if not math.isfinite(seconds):
        raise ConfigError(f"a time must be a finite number of seconds, not {seconds!r}", where)
