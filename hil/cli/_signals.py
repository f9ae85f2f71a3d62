"""SIGTERM ends a ``hil`` command the way Ctrl-C does.

``timeout``, systemd and a CI runner's cancel send SIGTERM, whose default action ends the process at once:
no summary, no Disarm, children left running (issue 25, finding 3). Every command already ends cleanly on
Ctrl-C, through ``KeyboardInterrupt``: ``hil run`` writes its summary and disarms the board it holds,
``hil calibrate`` puts its bench back to rest, ``hil montecarlo`` cancels its pending runs and closes its
cluster, ``hil gcs`` stops serving. So SIGTERM is turned into that same exception rather than given a path
of its own: :func:`interrupts_raise` installs one handler for both signals, which raises
:class:`Interrupted` — a ``KeyboardInterrupt`` that knows its signal, so what ends the command can say
which (``interrupted (SIGTERM)``) while every ``except KeyboardInterrupt`` on the way keeps working.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType

HANDLED = (signal.SIGINT, signal.SIGTERM)


class Interrupted(KeyboardInterrupt):
    """The command was asked to stop by signal ``signum`` (SIGINT or SIGTERM)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def signal_of(exc: BaseException) -> signal.Signals:
    """The signal behind an interrupt: :class:`Interrupted`'s own, else SIGINT (a bare ``KeyboardInterrupt``
    is Python's default SIGINT handler's)."""
    return signal.Signals(getattr(exc, "signum", signal.SIGINT))


def exit_status(exc: BaseException) -> int:
    """128 + the signal's number (130 for SIGINT, 143 for SIGTERM): the shell's status for a process the
    signal ended, which a command that ends cleanly on it still reports unless it documents its own."""
    return 128 + int(signal_of(exc))


def _raise_interrupted(signum: int, frame: FrameType | None) -> None:
    raise Interrupted(signum)


@contextmanager
def interrupts_raise() -> Iterator[None]:
    """Within the block, SIGINT and SIGTERM raise :class:`Interrupted` in the main thread; the previous
    handlers come back after it. A signal ignored when the process started (``nohup``, a background job
    of a non-interactive shell) stays ignored, as POSIX asks of programs that catch signals. Outside the
    main thread (``main()`` called from a thread) nothing is installed: Python allows handlers only there."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {}
    for signum in HANDLED:
        if signal.getsignal(signum) is signal.SIG_IGN:
            continue
        previous[signum] = signal.signal(signum, _raise_interrupted)
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, signal.SIG_DFL if handler is None else handler)  # None: set outside Python
