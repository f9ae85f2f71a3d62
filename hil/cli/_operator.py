"""The bench operator at the terminal: a prompt on stdout, the answer (Enter) read by a thread.

``hil calibrate`` keeps servicing the board while the operator connects an ESC's supply
(:mod:`hil.calibration.operator`); :class:`TerminalOperator` is the side that reads the terminal. One
daemon thread reads stdin line by line for the life of the command (a second thread would race the first
for the same line); a line answers the question pending when it arrives, a line with no question pending
is ignored. Input typed before a question is discarded when it is asked (``tcflush``), so an early or
stray Enter does not confirm a supply nobody connected. stdin must be a terminal: the answer is a
person's statement that the supply is connected, not something a script pipes in ahead of time.
"""

from __future__ import annotations

import sys
import termios
import threading
from typing import TextIO

from hil.calibration.operator import Answer
from protocol.errors import ConfigError


class TerminalOperator:
    """Questions on ``stdout``, answers from ``stdin`` (a terminal)."""

    def __init__(self, stdin: TextIO | None = None, stdout: TextIO | None = None) -> None:
        self._stdin = stdin if stdin is not None else sys.stdin
        self._stdout = stdout if stdout is not None else sys.stdout
        self._lock = threading.Lock()
        self._pending: Answer | None = None
        self._closed = False  # stdin reached its end: no answer can come
        self._reader: threading.Thread | None = None

    def ask(self, prompt: str) -> Answer:
        """Show ``prompt`` and return its :class:`Answer`, given when the operator presses Enter."""
        if not self._stdin.isatty():
            raise ConfigError("the board asks for the ESC supply: run on a terminal to confirm it", "stdin")
        answer = Answer()
        try:
            termios.tcflush(self._stdin.fileno(), termios.TCIFLUSH)  # nothing typed before the question
        except (termios.error, OSError, ValueError):
            pass  # not flushable (closed meanwhile): the reader thread reports the end of input
        with self._lock:
            if self._closed:
                answer.fail(ConfigError("stdin is closed: nobody can confirm the ESC supply", "stdin"))
                return answer
            self._pending = answer
            if self._reader is None:
                self._reader = threading.Thread(target=self._read, name="operator stdin", daemon=True)
                self._reader.start()
        print(
            f"{prompt}\nPress Enter once it is connected (Ctrl-C gives up): ", file=self._stdout, flush=True
        )
        return answer

    def _read(self) -> None:
        while True:
            try:
                line = self._stdin.readline()
            except (OSError, ValueError):
                line = ""
            with self._lock:
                answer, self._pending = self._pending, None
                if not line:
                    self._closed = True
            if not line:
                if answer is not None:
                    answer.fail(ConfigError("stdin closed before the ESC supply was confirmed", "stdin"))
                return
            if answer is not None:
                answer.give()
