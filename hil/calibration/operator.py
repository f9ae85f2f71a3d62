"""Asking the bench operator something without stopping the link to the board.

A board without an ESC supply switch holds its ESC procedure at ``WAIT_SUPPLY`` (its channel at the high
endpoint, up to ``ESC_SUPPLY_WAIT_MS``) only while its link lives: a host that stops sending for the link
watchdog's timeout (250 ms by default) loses the link and the board aborts (``LINK_LOST``). A host that
blocked in ``input()`` until the operator pressed Enter did exactly that. So a question never blocks: an
:class:`Operator` returns an :class:`Answer` at once, which another thread (the terminal's reader) fills
in, and the loop that services the link polls it between its waits.
"""

from __future__ import annotations

import threading
from typing import Protocol

from protocol.errors import HilError


class Answer:
    """One question's answer, given from another thread (:meth:`give`, :meth:`fail`), polled by the loop
    that services the link (:meth:`ready`, :meth:`wait`)."""

    def __init__(self) -> None:
        self._given = threading.Event()
        self._error: HilError | None = None

    def give(self) -> None:
        """The operator answered (did what was asked)."""
        self._given.set()

    def fail(self, error: HilError) -> None:
        """No answer can come (the terminal closed): :meth:`ready` raises ``error``."""
        self._error = error
        self._given.set()

    def ready(self) -> bool:
        """Whether the operator has answered (never waits); raises the error :meth:`fail` stored."""
        if not self._given.is_set():
            return False
        if self._error is not None:
            raise self._error
        return True

    def wait(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` wall-clock seconds for the answer (see :meth:`ready`)."""
        self._given.wait(max(timeout_s, 0.0))
        return self.ready()


class Operator(Protocol):
    """Who answers the bench's questions: ``ask(prompt)`` shows the prompt and returns at once."""

    def ask(self, prompt: str) -> Answer: ...
