"""Injected clocks. Every loop, watchdog and pulse generator takes one, so the same code runs in real time
or in lockstep (simulated time, as fast as the CPU allows).

``now()`` is seconds (float) on the clock's own monotonic time base. Loops schedule against absolute
deadlines (``t_next += period``) with ``sleep_until(t_next)``, never ``sleep(period)``, so that period
errors do not accumulate.
"""

from __future__ import annotations

import threading
import time
from typing import Protocol


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
        while True:
            remaining = deadline - self.now()
            if remaining <= 0.0:
                return
            time.sleep(remaining)


class LockstepClock:
    """Simulated time that only moves when told to. ``sleep_until`` jumps to the deadline (single
    driver) — a lockstep loop owns the clock and advances it itself. Thread-safe reads."""

    def __init__(self, start: float = 0.0) -> None:
        self._t = float(start)
        self._lock = threading.Lock()

    def now(self) -> float:
        return self._t  # one attribute read: atomic, no lock needed (called tens of times per tick)

    def advance(self, dt: float) -> float:
        """Move time forward by ``dt`` ≥ 0 seconds; returns the new time."""
        if dt < 0:
            raise ValueError(f"cannot move a clock backwards (dt={dt})")
        with self._lock:
            self._t += dt
            return self._t

    def set(self, t: float) -> None:
        """Jump to ``t`` (not earlier than now)."""
        with self._lock:
            if t < self._t:
                raise ValueError(f"cannot move a clock backwards ({t} < {self._t})")
            self._t = float(t)

    def sleep_until(self, deadline: float) -> None:
        with self._lock:
            if deadline > self._t:
                self._t = float(deadline)
