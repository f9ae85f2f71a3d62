"""Exact periodic schedules in integer microseconds (no accumulated rounding at 490 Hz and the like)."""

from __future__ import annotations

import math


class Periodic:
    """Deadlines ``origin + round(k · 1e6 / rate_hz)`` µs for k = 0, 1, 2, …; ``enabled`` gates it."""

    __slots__ = ("rate_hz", "origin_us", "k", "due_us", "enabled")

    def __init__(self, rate_hz: float) -> None:
        self.rate_hz = rate_hz
        self.origin_us = 0
        self.k = 0
        self.due_us = 0
        self.enabled = False

    def start(self, origin_us: int, first_offset: bool = False) -> None:
        """Start at ``origin_us`` (first deadline there, or one period later with ``first_offset``)."""
        self.origin_us = origin_us
        self.k = 1 if first_offset else 0
        self.due_us = self._at(self.k)
        self.enabled = True

    def stop(self) -> None:
        self.enabled = False

    @property
    def next_us(self) -> float:
        return self.due_us if self.enabled else math.inf

    def is_due(self, t_us: int) -> bool:
        return self.enabled and t_us >= self.due_us

    def advance(self, t_us: int) -> None:
        """Move past ``t_us`` (deadlines missed while disabled or in one jump are skipped, not replayed)."""
        while self.due_us <= t_us:
            self.k += 1
            self.due_us = self._at(self.k)

    def _at(self, k: int) -> int:
        return self.origin_us + round(k * 1_000_000 / self.rate_hz)

    @property
    def period_us(self) -> float:
        return 1_000_000 / self.rate_hz
