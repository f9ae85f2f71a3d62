"""The signals that stop a ``hil`` command, held back while a block must not be cut short.

hil's command line turns SIGINT, SIGTERM and SIGHUP (:data:`STOP_SIGNALS`) into an exception raised
wherever the main thread happens to be (:mod:`hil.cli._signals`). Some blocks must not be thrown away half
done by it, and two ways of holding them are wanted, both here:

* **A run's ending** (:class:`HeldSignals`). Once a run's loop has ended, the main thread is in its
  clean-up: the board disarmed, the link closed, the summary gathered, the logs closed, ``summary.json``
  written. A second Ctrl-C there (a user pressing it twice) once threw the clean-up away half done: no
  ``summary.json`` at all, or one without its ``exit``; and a second signal microseconds after the first
  (CI's drawn moments found it twice) could land on the entry of the exit callback that disarms the
  board, or between two of the ExitStack's callbacks: no Disarm sent and none said, with a board armed
  at the interrupt. :class:`HeldSignals` puts a handler of its own in front of those signals' Python
  handlers for the whole run. Until the run starts ending it hands a signal on to the handler it
  replaced (so an interrupt interrupts the run) and, in the same step, sets :attr:`HeldSignals.holding`;
  the run sets it too when its loop ends on its own (a plain attribute store, so no signal can slip in
  between the run's end and the hold). While it holds, the next signal is noted in
  :attr:`HeldSignals.received` instead, and the caller decides what it means (:func:`hil.runtime.loop.run`
  reports one that came after a run ended on its own in :attr:`~hil.runtime.loop.RunResult.late_signal`;
  after an interrupt it is the same request again). One signal is held, not more: one more (a disk that
  stalls the ending, a board whose Disarm is not answered, a user pressing Ctrl-C again and again) goes
  to its handler as before and gives the ending up — the run never becomes one that only SIGKILL ends.
* **A step that cannot be left half made** (:func:`deferred`): a Dask cluster starting or closing. Every
  signal is held for the block, then handed to the handler that was there: a LocalCluster interrupted
  while it started was left half made, and Dask's exit hook failed an assertion closing it, with a
  traceback; a second Ctrl-C during the close left Dask's exit hook 10 s more of closing after the command
  had said it was interrupted.

The handlers replaced come back after the block. Only the main thread can change handlers (Python runs
them there); elsewhere (a Monte Carlo worker's thread) nothing is installed and nothing held. A signal
with no Python handler (ignored, or the OS's default action) is left as it is.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from types import FrameType, TracebackType
from typing import Any

STOP_SIGNALS = tuple(
    s for s in (getattr(signal, name, None) for name in ("SIGINT", "SIGTERM", "SIGHUP")) if s is not None
)
"""The signals that end a command the way Ctrl-C does: SIGINT, SIGTERM, and SIGHUP (the terminal or ssh
session the command was started from closed: its default action ended the process at once — no summary,
the board left armed until its own watchdog failed it safe)."""


def first_signal(exc: BaseException) -> signal.Signals:
    """The signal behind the first interrupt in ``exc``'s chain: hil's CLI raises a ``KeyboardInterrupt``
    carrying ``signum`` (:mod:`hil.cli._signals`); a bare one is Python's own SIGINT handler's. A second
    signal raised while the first one's exception was unwinding carries the first as its
    ``__context__``: the command was interrupted by that first one (a run once said
    ``interrupted (SIGINT)`` for a SIGTERM followed by a Ctrl-C, and ``hil calibrate`` the same)."""
    first, seen = exc, {id(exc)}
    context = exc.__context__
    while context is not None and id(context) not in seen:
        seen.add(id(context))
        if isinstance(context, KeyboardInterrupt):
            first = context
        context = context.__context__
    return signal.Signals(getattr(first, "signum", signal.SIGINT))


class HeldSignals:
    """Within ``with``: a :data:`STOP_SIGNALS` signal that has a Python handler goes to it while
    :attr:`holding` is false, and sets it (the run is ending now); once it is set the next one is noted in
    :attr:`received` (its name), any after that goes to its handler."""

    def __init__(self) -> None:
        self.holding = False
        self.received: list[str] = []
        self._previous: dict[int, Callable[[int, FrameType | None], Any]] = {}

    def __enter__(self) -> HeldSignals:
        if threading.current_thread() is threading.main_thread():
            for signum in STOP_SIGNALS:
                handler = signal.getsignal(signum)
                if callable(handler):
                    self._previous[signum] = handler
                    signal.signal(signum, self._handle)
        return self

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        if not self.holding:
            self.holding = True  # before the interrupt is raised: the next signal cannot cut its unwinding
        elif not self.received:
            self.received.append(signal.Signals(signum).name)
            return
        self._previous[signum](signum, frame)  # hil's: raises the interrupt

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        for signum, handler in list(self._previous.items()):
            signal.signal(signum, handler)  # a signal meanwhile still finds its handler in _previous


@contextmanager
def deferred() -> Iterator[None]:
    """:data:`STOP_SIGNALS` held for the block, then handled as they would have been: the handler that was
    there is called with the first (``hil``'s raises its interrupt), or, where that was the OS's default
    action, the signal is raised again. Ignored signals stay ignored. A block that fails after an interrupt
    came is reported as the interrupt (a worker process the block reached died starting)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    previous: dict[int, Any] = {}
    for signum in STOP_SIGNALS:
        handler = signal.getsignal(signum)
        if handler is signal.SIG_IGN or handler is None:
            continue
        previous[signum] = signal.signal(signum, lambda received, frame: caught.append(received))
    try:
        yield
    except Exception:
        if not caught:
            raise
        # the block failed because of the interrupt: the interrupt is what happened, handled as such
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
    if caught:
        handler = previous[caught[0]]
        if callable(handler):
            handler(caught[0], None)
        else:  # SIG_DFL: what the signal would have done
            signal.raise_signal(caught[0])
