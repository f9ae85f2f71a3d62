"""Exact periodic schedules in integer microseconds (no accumulated rounding at 490 Hz and the like)."""

from __future__ import annotations

import math


class Periodic:
    """Deadlines ``origin + round(k · 1e6 / rate_hz)`` µs for k = 0, 1, 2, …; ``enabled`` gates it.

    ``next_us`` is the next deadline while enabled, inf while stopped: a plain attribute kept by
    ``start``/``stop``/``advance`` (the board reads it for every schedule at every event)."""

    __slots__ = ("rate_hz", "origin_us", "k", "due_us", "enabled", "next_us")

    def __init__(self, rate_hz: float) -> None:
        self.rate_hz = rate_hz
        self.origin_us = 0
        self.k = 0
        self.due_us = 0
        self.enabled = False
        self.next_us: float = math.inf

    def start(self, origin_us: int, first_offset: bool = False) -> None:
        """Start at ``origin_us`` (first deadline there, or one period later with ``first_offset``)."""
        self.origin_us = origin_us
        self.k = 1 if first_offset else 0
        self.due_us = self._at(self.k)
        self.enabled = True
        self.next_us = self.due_us

    def stop(self) -> None:
        self.enabled = False
        self.next_us = math.inf

    def is_due(self, t_us: int) -> bool:
        return t_us >= self.next_us

    def advance(self, t_us: int) -> None:
        """Move past ``t_us`` (deadlines missed while disabled or in one jump are skipped, not replayed)."""
        while self.due_us <= t_us:
            self.k += 1
            self.due_us = self._at(self.k)
        if self.enabled:
            self.next_us = self.due_us

    def _at(self, k: int) -> int:
        return self.origin_us + round(k * 1_000_000 / self.rate_hz)

    @property
    def period_us(self) -> float:
        return 1_000_000 / self.rate_hz
