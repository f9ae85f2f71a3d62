"""How far a bench procedure has got and how long the rest should take, for the operator's screen.

A sweep of a rotor on a real bench takes minutes, teaching an ESC several seconds with nothing to see:
each step is reported as it finishes (``report(line)``, the CLI prints it) with the time spent and an
estimate of the time left. :class:`Eta` estimates from the steps done so far on the wall clock (the
operator's time: a lockstep emulator's simulated seconds pass faster), the mean time per step times the
steps left; the first estimate comes after the first step.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

Report = Callable[[str], None]
"""Where a procedure's progress lines go (``print`` in the CLI; nothing by default)."""


def no_report(line: str) -> None:
    """The default :data:`Report`: progress is not shown."""


def duration(seconds: float) -> str:
    """``seconds`` as an operator reads it: ``0.4 s``, ``25 s``, ``3 min 05 s``, ``1 h 02 min``."""
    if not math.isfinite(seconds):
        return "unknown"
    s = max(seconds, 0.0)
    if s < 10.0:
        return f"{s:.1f} s"
    whole = int(round(s))
    if whole < 60:
        return f"{whole} s"
    if whole < 3600:
        return f"{whole // 60} min {whole % 60:02d} s"
    return f"{whole // 3600} h {whole % 3600 // 60:02d} min"


@dataclass
class Eta:
    """``total`` steps timed on ``clock`` (s, monotonic) from construction; :meth:`step` after each."""

    total: int
    clock: Callable[[], float] = time.monotonic
    done: int = 0
    started: float = field(init=False)

    def __post_init__(self) -> None:
        self.started = self.clock()

    def step(self) -> None:
        self.done += 1

    @property
    def elapsed_s(self) -> float:
        return self.clock() - self.started

    @property
    def left_s(self) -> float:
        """Estimated seconds to the last step (inf before the first step is done)."""
        if self.done <= 0:
            return math.inf
        return self.elapsed_s / self.done * max(self.total - self.done, 0)

    def text(self) -> str:
        """``12/51, 25 s elapsed, about 1 min 20 s left``."""
        left = "done" if self.done >= self.total else f"about {duration(self.left_s)} left"
        return f"{self.done}/{self.total}, {duration(self.elapsed_s)} elapsed, {left}"
