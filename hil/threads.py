"""A background thread's error, kept for the thread's owner to raise in its own thread.

A thread that dies on an exception only prints it (``threading.excepthook``): the owner — a run loop, a
test, a server's ``close()`` — carries on as if nothing happened. Every long-lived thread of the host and
of the far side (the board's pty and CAN servers, the world's streamer, the phone receivers, the board
client's reader, the ground station's pump, the CSV writer) therefore stores the exception it dies of in
a :class:`ThreadError`, and its owner calls :meth:`ThreadError.check` where it can act on it: on its next
call, on ``close()``.

Two kinds of owner, two variants (chosen by ``once``):

- **broken for good** (the default): the error is raised by every later ``check()``; the thread is gone,
  so everything the owner does afterwards would act on a dead link. Raised as a
  :class:`~protocol.errors.LinkError` naming what failed (``what``), chained to the thread's exception,
  except for the types given as ``as_is`` (the board client raises its session's own
  :class:`~protocol.errors.HilError` unchanged: an incompatible board is a handshake error, not a link
  error).
- **raised once** (``once=True``): the error is cleared as it is raised, and raised as it is (``what`` is
  ``None``). The CSV writer's owner sees its full disk once, on the write, flush or close that follows it.

Not thread-safe beyond what a single attribute assignment is: one thread stores, the owner checks; an
owner that must also wake waiters does so under its own lock (the board client's condition).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from protocol.errors import LinkError

__all__ = ["ThreadError"]


class ThreadError:
    """The error a background thread died of (or the first fatal one it met), for its owner to raise.

    ``what``: what failed, for the message (``"CAN server on can://vcan0 failed"``), or a callable giving
    it when it is known only after construction (a phone receiver's bound URL); ``None`` to raise the
    error as it is. ``as_is``: exception types raised as they are even with a ``what``. ``once``: clear
    the error as it is raised (otherwise every later :meth:`check` raises it again).
    """

    __slots__ = ("_what", "_as_is", "_once", "error")

    def __init__(
        self,
        what: str | Callable[[], str] | None,
        *,
        as_is: type[BaseException] | tuple[type[BaseException], ...] = (),
        once: bool = False,
    ) -> None:
        self._what = what
        self._as_is = as_is
        self._once = once
        self.error: BaseException | None = None  # the stored exception; None while the thread is well

    def store(self, exc: BaseException) -> None:
        """Keep ``exc`` for the owner (a later one replaces it)."""
        self.error = exc

    def clear(self) -> None:
        """Forget the stored error (an owner that has just raised it itself, e.g. a failed first connect)."""
        self.error = None

    def check(self) -> None:
        """Raise the stored error, if there is one (see the class's variants). Cheap when there is none: it
        sits on the owners' per-tick paths (a receiver's ``drain``, the board client's pump)."""
        error = self.error
        if error is None:
            return
        if self._once:
            self.error = None
        what = self._what
        if what is None or isinstance(error, self._as_is):
            raise error
        described = what if isinstance(what, str) else what()
        raise LinkError(f"{described}: {error!r}") from error

    @contextmanager
    def caught(self, logger: logging.Logger | None = None, message: str = "") -> Iterator[None]:
        """Run a thread's body under this: any exception (``BaseException``: a ``SystemExit`` in a
        thread is a failure of the thread, not the process's exit) is stored instead of ending the thread
        silently, and logged on ``logger`` when given (``message``: what failed): with its traceback,
        except a :class:`~protocol.errors.LinkError` — the far side gone, a bus closed: an event its
        message names whole, not a bug to trace — logged as one line."""
        try:
            yield
        except BaseException as exc:  # stored, raised by the owner's check(): threads never die silently
            self.error = exc
            if logger is not None and isinstance(exc, LinkError):
                logger.error("%s: %s", message, exc)
            elif logger is not None:
                logger.exception(message)
