"""A kind of line logged (or recorded) at most so many times per interval: a flood of it counted, not
written — a board or a phone must not bury the host's own lines, nor grow its log by megabytes a second."""

from __future__ import annotations

import math


class Throttle:
    """One kind of line, at most ``lines`` of it per ``every_s`` (s, on whatever clock the caller's ``now``
    is; a window opens at the first line after the last window ended): :meth:`due` says whether a line may
    be written now, and how many were held back since the last one."""

    def __init__(self, every_s: float, lines: int = 1) -> None:
        self.every_s = every_s
        self.lines = lines
        self._window = -math.inf  # when the current window began
        self._written = 0  # lines written in it
        self._held = 0

    def due(self, now: float, count: int = 1) -> int | None:
        """How many were held back since the last line, when a line may be written at ``now``; None when
        not (these ``count`` held back, and counted for the next line)."""
        if now - self._window >= self.every_s:
            self._window, self._written = now, 0
        if self._written >= self.lines:
            self._held += count
            return None
        self._written += 1
        held, self._held = self._held, 0
        return held
