"""``firmware-sim``'s status lines: what the board goes through, said on stderr as it happens — a host
arriving (its first bytes), leaving (EIO, or silent for ``HOST_SILENCE_S``), coming back, and every state
change (DISARMED after the handshake, ARMED, FAILSAFE), each with the board's time.

It reads any server through :class:`.base.BoardServer` only, so a pty, a CAN bus and the firmware under
simavr are reported alike (a CAN server once lacked an attribute the pty's had: the status thread died).
An error in the thread is stored and raised by :meth:`StatusLines.stop`, never swallowed.
"""

from __future__ import annotations

import logging
import sys
import threading
from typing import TextIO

from hil.threads import ThreadError
from protocol.messages import BoardState

from .base import HOST_SILENCE_S, BoardServer

logger = logging.getLogger(__name__)


class StatusLines:
    """A thread that looks at ``server`` every ``period_s`` seconds and writes what changed to ``out``."""

    def __init__(self, server: BoardServer, period_s: float = 0.1, out: TextIO | None = None) -> None:
        self.server = server
        self.period_s = period_s
        self.out = out if out is not None else sys.stderr
        self.lines: list[str] = []  # everything said, for tests and the final summary
        self.out_gone = False  # ``out`` could not be written (a hung-up terminal): the lines are only kept
        self._present = False
        self._gone = 0
        self._state: BoardState | None = None
        self._stop = threading.Event()
        self._thread_error = ThreadError("firmware-sim's status thread failed")
        self._thread = threading.Thread(target=self._run, name="firmware-sim-status", daemon=True)

    def start(self) -> StatusLines:
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the thread; raises its error, if it had one."""
        self._stop.set()
        self._thread.join(timeout=1.0)
        self._thread_error.check()

    def look(self) -> None:
        """One look at the server: a line for each thing that changed since the last."""
        server = self.server
        now = server.board_time()
        stats = server.stats
        if stats.host_gone > self._gone:
            self._gone = stats.host_gone
            if self._present:
                why = f"closed the port, or silent for {HOST_SILENCE_S:g} s"
                self._say(now, f"host left ({why}); waiting for it")
            self._present = False
        if stats.host_present and not self._present:
            self._present = True
            self._say(now, "host connected" if stats.reconnects == 0 else "host connected again")
        for at, state in server.take_transitions():  # every change, however brief, at its own time
            if self._state is not None:
                self._say(at, f"board {self._state.name} -> {state.name}")
            self._state = state

    def _say(self, now: float, what: str) -> None:
        """Keep the line and write it to :attr:`out`, unless that stream is gone: a terminal closed under
        the command (its writes fail with EIO) or a pipe nobody reads any more. The lines are what the
        command says, not what it does: writing them once failed the thread, whose error then stopped the
        command's clean-up before the pty was closed and the ``--link`` symlink removed (exit status 1)."""
        line = f"firmware-sim: {now:8.2f} s  {what}"
        self.lines.append(line)
        if self.out_gone:
            return
        try:
            print(line, file=self.out, flush=True)
        except (OSError, ValueError):  # EIO / EPIPE, or a stream closed: said nowhere from now on
            self.out_gone = True

    def _run(self) -> None:
        with self._thread_error.caught(logger, "status thread failed"):
            while not self._stop.wait(self.period_s):
                self.look()
