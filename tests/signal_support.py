"""A second signal at a chosen function call after the first: how the tests put it exactly where a
scheduler puts it only now and then (CI's drawn moments found a SIGTERM 5.5 µs after a SIGINT landing on
the entry of the function that disarms the board).

:meth:`SecondSignal.raise_first` starts a trace function that counts function calls and raises the first
signal (hil's handler, installed by :func:`hil.cli._signals.interrupts_raise`, raises its interrupt); at
the ``at_call``-th call the trace raises the second signal, which Python handles at the next instruction
that checks: the called function's first.
"""

from __future__ import annotations

import signal
import sys
from types import FrameType
from typing import Any


class SecondSignal:
    """``second`` raised at the ``at_call``-th function call after the first signal was raised."""

    def __init__(self, second: int, at_call: int) -> None:
        self.second, self.at_call = second, at_call
        self.calls = 0
        self.sent_second = False

    def named(self, first: int) -> set[str]:
        """The signals an interrupted command may name: the first, or — the second raised on the first
        call, the first one's handler's, before it ran a line — either: both were pending then, and
        Python runs pending handlers by signal number, not in the order the signals came."""
        names = {signal.Signals(first).name}
        return names | {signal.Signals(self.second).name} if self.at_call == 1 else names

    def raise_first(self, first: int) -> None:
        """Raise ``first`` now, counting calls from here (its handler's are the first ones)."""
        sys.settrace(self._trace)
        signal.raise_signal(first)

    def _trace(self, frame: FrameType, event: str, arg: Any) -> None:
        if event == "call" and not self.sent_second:
            self.calls += 1
            if self.calls >= self.at_call:
                self.sent_second = True
                sys.settrace(None)
                signal.raise_signal(self.second)
