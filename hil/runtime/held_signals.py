"""Interrupts held back while a run writes its ending.

hil's command line turns SIGINT, SIGTERM and SIGHUP into an exception raised wherever
the main thread happens to be (:mod:`hil.cli._signals`). Once a run's loop has ended, that place is its
clean-up: the link being closed, the summary being gathered, the logs being closed, ``summary.json`` being
written. A second Ctrl-C there (a user pressing it twice) once threw the clean-up away half done: no
``summary.json`` at all, or one without its ``exit``.

:class:`HeldSignals` puts a handler of its own in front of those signals' Python handlers for the whole
run. Until the run starts ending it hands every signal on to the handler it replaced (so an interrupt
interrupts the run, and a second one the Disarm wait, as before); once :attr:`HeldSignals.holding` is set —
a plain attribute store, so no signal can slip in between the run's end and the hold — it notes the first
signal in :attr:`HeldSignals.received` instead, and the caller decides what it means
(:func:`hil.runtime.loop.run` reports it in :attr:`~hil.runtime.loop.RunResult.late_signal`). One signal is
held, not more: one repeated while the ending is written (a disk that stalls it, a user pressing Ctrl-C
again and again) goes to its handler as before and gives the ending up — the run never becomes one that
only SIGKILL ends. The handlers it replaced come back when the run is over.

Only the main thread can change handlers (Python runs them there); elsewhere (a Monte Carlo worker's
thread) nothing is installed and nothing held. A signal with no Python handler (ignored, or the OS's
default action) is left as it is.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable
from types import FrameType, TracebackType
from typing import Any

HELD = tuple(
    s for s in (getattr(signal, name, None) for name in ("SIGINT", "SIGTERM", "SIGHUP")) if s is not None
)


class HeldSignals:
    """Within ``with``: :data:`HELD` signals that have a Python handler go to it while :attr:`holding` is
    false; once it is set the first one is noted in :attr:`received` (its name), any after it goes to
    its handler."""

    def __init__(self) -> None:
        self.holding = False
        self.received: list[str] = []
        self._previous: dict[int, Callable[[int, FrameType | None], Any]] = {}

    def __enter__(self) -> HeldSignals:
        if threading.current_thread() is threading.main_thread():
            for signum in HELD:
                handler = signal.getsignal(signum)
                if callable(handler):
                    self._previous[signum] = handler
                    signal.signal(signum, self._handle)
        return self

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        if self.holding and not self.received:
            self.received.append(signal.Signals(signum).name)
            return
        self._previous[signum](signum, frame)  # hil's: raises the interrupt

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        for signum, handler in list(self._previous.items()):
            signal.signal(signum, handler)  # a signal meanwhile still finds its handler in _previous
