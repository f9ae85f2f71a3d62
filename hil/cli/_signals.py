"""SIGTERM (and SIGHUP) end a ``hil`` command the way Ctrl-C does.

``timeout``, systemd and a CI runner's cancel send SIGTERM, whose default action ends the process at once:
no summary, no Disarm, children left running (issue 25, finding 3). Every command already ends cleanly on
Ctrl-C, through ``KeyboardInterrupt``: ``hil run`` writes its summary and disarms the board it holds,
``hil calibrate`` puts its bench back to rest, ``hil montecarlo`` cancels its pending runs and closes its
cluster, ``hil gcs`` stops serving. So SIGTERM is turned into that same exception rather than given a path
of its own: :func:`interrupts_raise` installs one handler for both signals, which raises
:class:`Interrupted` — a ``KeyboardInterrupt`` that knows its signal, so what ends the command can say
which (``interrupted (SIGTERM)``) while every ``except KeyboardInterrupt`` on the way keeps working.

An exception raised where Python cannot propagate it — in a ctypes callback (numba's LLVM object cache
calls one for every function it compiles), a ``__del__``, a weakref callback — is printed as "Exception
ignored" and dropped. A signal whose handler ran there was lost: a Ctrl-C during the first run's kernel
compile printed a traceback, and the run went on and said it completed. :func:`interrupts_raise` therefore
also hooks :data:`sys.unraisablehook`: an interrupt dropped that way is sent again to the process, so its
handler runs at the next point where an exception can propagate.
"""

from __future__ import annotations

import atexit
import contextlib
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from types import FrameType

from hil.runtime.held_signals import STOP_SIGNALS, first_signal

HANDLED = STOP_SIGNALS
"""The signals that end a command the way Ctrl-C does (:data:`hil.runtime.held_signals.STOP_SIGNALS`)."""


class Interrupted(KeyboardInterrupt):
    """The command was asked to stop by signal ``signum`` (one of :data:`HANDLED`)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def signal_of(exc: BaseException) -> signal.Signals:
    """The signal behind an interrupt: the first one's of ``exc``'s chain (a second signal raised while
    the first one's exception unwound names the first; :func:`hil.runtime.held_signals.first_signal`)."""
    return first_signal(exc)


def exit_status(exc: BaseException) -> int:
    """128 + the signal's number (130 for SIGINT, 143 for SIGTERM): the shell's status for a process the
    signal ended, which a command that ends cleanly on it still reports unless it documents its own."""
    return 128 + int(signal_of(exc))


_ended: list[int] = []
"""The command's exit status once it has one (its own process only: :func:`exit_on_late_signals`)."""


def _raise_interrupted(signum: int, frame: FrameType | None) -> None:
    if _ended:  # the command has ended: the process ends now, with its status
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):  # a closed or broken stream: nothing more to say there
                stream.flush()
        os._exit(_ended[0])
    if _in_unraisable_hook:  # raised here, it would be dropped as the hook's own: sent again later instead
        _send_again_later(signum)
        return
    raise Interrupted(signum)


_in_unraisable_hook = False
"""Whether the main thread is in :func:`_redeliver_dropped_interrupts`'s hook (a plain global: storing it
runs no Python call, so no signal handler can run between the store and the hook's return)."""

REDELIVERY_DELAY_S = 0.002
"""How long after an interrupt was dropped its signal is sent again (s): long enough for the callback
that dropped it to return, as a rule; a signal that comes back inside one is dropped and sent again."""


def _send_again_later(signum: int) -> None:
    """Send ``signum`` to this process from a thread of its own, :data:`REDELIVERY_DELAY_S` from now."""
    timer = threading.Timer(REDELIVERY_DELAY_S, os.kill, args=(os.getpid(), signum))
    timer.daemon = True
    timer.start()


@contextmanager
def interrupts_raise(restore: bool = True) -> Iterator[None]:
    """Within the block, the :data:`HANDLED` signals raise :class:`Interrupted` in the main thread; the
    previous handlers come back after it (``restore``; a command's own process keeps them, for
    :func:`exit_on_late_signals` to replace: a signal between the two would meet Python's default handler,
    whose KeyboardInterrupt outside every ``except`` kills the process by SIGINT — status −2 for a command
    that had finished). A signal ignored when the process started (``nohup``, a background job of a
    non-interactive shell) stays ignored, as POSIX asks of programs that catch signals. Outside the main
    thread (``main()`` called from a thread) nothing is installed: Python allows handlers only there."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {}
    for signum in HANDLED:
        if signal.getsignal(signum) is signal.SIG_IGN:
            continue
        previous[signum] = signal.signal(signum, _raise_interrupted)
    previous_hook = sys.unraisablehook
    sys.unraisablehook = _redeliver_dropped_interrupts(previous_hook)
    try:
        yield
    finally:
        for signum, handler in previous.items() if restore else ():
            signal.signal(signum, signal.SIG_DFL if handler is None else handler)  # None: set outside Python
        if restore:
            sys.unraisablehook = previous_hook


def _redeliver_dropped_interrupts(
    previous: Callable[[sys.UnraisableHookArgs], object],
) -> Callable[[sys.UnraisableHookArgs], None]:
    """An unraisable-exception hook that has a dropped interrupt's signal sent to this process again, and
    hands every other unraisable exception to ``previous`` (Python's default prints it).

    The signal is sent from a thread of its own, a moment after the hook has returned: sent from the hook
    itself (``signal.raise_signal``, ``os.kill``), Python runs its handler at once, inside the hook, whose
    exception is dropped in turn (and so is one whose handler runs while the hook still runs: the handler
    sends it again later, :func:`_raise_interrupted`). Sent later, the handler runs where the main thread
    is then; should that be another such callback, the interrupt is dropped there and sent again, until
    it lands where it propagates. A process that can start no thread (its interpreter shutting down) has
    its interrupt printed, as before."""

    def hook(unraisable: sys.UnraisableHookArgs) -> None:
        global _in_unraisable_hook
        exc = unraisable.exc_value
        if isinstance(exc, KeyboardInterrupt) and threading.current_thread() is threading.main_thread():
            _in_unraisable_hook = True
            try:
                _send_again_later(getattr(exc, "signum", signal.SIGINT))
            except RuntimeError:  # no new thread at interpreter shutdown
                _in_unraisable_hook = False
                previous(unraisable)
                return
            _in_unraisable_hook = False
            return
        previous(unraisable)

    return hook


def exit_on_late_signals(status: int) -> None:
    """The command has ended with ``status``: from now on a :data:`HANDLED` signal that comes while the
    interpreter exits — a second Ctrl-C just after the first ended the command, a supervisor's SIGTERM —
    ends the process at once with that status (through :func:`interrupts_raise`'s handlers, kept by a
    command's own process), rather than raising an interrupt outside every ``except``: a traceback, or
    death by the signal, for a command whose work was done."""
    _ended[:] = [status]


def ignore_signals_at_last_exit_hook() -> None:
    """Register, as the exit hook to run last (the first registered: they run in reverse), one that ignores
    the :data:`HANDLED` signals. Python's finalization, after the exit hooks, puts the OS's default action
    back for every signal it had a Python handler for; one arriving then — at whichever thread of the
    process the kernel picks — killed the finished command (status −2 after a run that had printed its
    summary). Ignored, such a signal is dropped and the process ends with its command's status (Python
    leaves an ignored signal ignored). Exit hooks registered later (Dask's, logging's) run before it, still
    interruptible."""
    atexit.register(_ignore_handled)


def _ignore_handled() -> None:
    for signum in HANDLED:
        signal.signal(signum, signal.SIG_IGN)
