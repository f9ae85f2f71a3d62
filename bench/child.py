"""A program in a process of its own that says on its first stdout line where to reach it — ``firmware-sim``
printing its pty path or its ``can://`` URL, a peer printing its pty — for the benchmarks, the soak and the
tests that drive one from outside.

One way to start such a child, wait for that line, and stop it: :func:`started`. Its stderr is read all
the time by a thread (a child's status lines filling a pipe nobody reads would stall it), and what it said
is on :attr:`Child.said` once it stopped — for the final line a test checks, or for the error when it did
not start.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field

STOP_WAIT_S = 20.0
"""How long a stopped child may take to exit before it is killed (s): a firmware-sim under simavr saves
its EEPROM and prints its statistics on the way out."""


@dataclass
class Child:
    """A started child: its process, its first stdout line (stripped), and what it said on stderr."""

    proc: subprocess.Popen[str]
    first_line: str
    _said: list[str] = field(default_factory=list)
    _reader: threading.Thread | None = None

    @property
    def said(self) -> str:
        """Its stderr so far (all of it once it stopped)."""
        return "".join(self._said)

    def stop(self, how: int = signal.SIGTERM) -> int:
        """Send ``how`` (killed after :data:`STOP_WAIT_S`), wait, and return its exit status."""
        if self.proc.poll() is None:
            self.proc.send_signal(how)
            try:
                self.proc.wait(timeout=STOP_WAIT_S)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self._reader is not None:
            self._reader.join(timeout=5)
        return int(self.proc.returncode)


def firmware_sim(*options: str) -> list[str]:
    """The command line of ``python -m firmware_sim`` with ``options``, in this interpreter."""
    return [sys.executable, "-m", "firmware_sim", *options]


@contextmanager
def started(
    argv: Sequence[str], ready: str | tuple[str, ...] = "", stop: int = signal.SIGTERM
) -> Iterator[Child]:
    """Start ``argv``; wait for its first stdout line, which must start with ``ready`` (one of them); yield
    the :class:`Child`; stop it with the signal ``stop`` on the way out. RuntimeError, with what it said,
    when it ends or prints something else first. Its stdin is a pipe (``proc.stdin``), for a child that takes
    requests there; a child that waits on it is not woken by an end of file it did not ask for."""
    proc = subprocess.Popen(
        list(argv),
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    child = Child(proc, "")
    assert proc.stdout is not None and proc.stderr is not None
    stderr = proc.stderr
    child._reader = threading.Thread(
        target=lambda: child._said.extend(iter(stderr.readline, "")), name="child-stderr", daemon=True
    )
    child._reader.start()
    try:
        child.first_line = proc.stdout.readline().strip()
        if not child.first_line or not child.first_line.startswith(ready):
            child.stop(signal.SIGKILL)
            said = (child.first_line + "\n" + child.said)[-2000:]
            raise RuntimeError(f"{' '.join(argv[:4])} did not start (exit {proc.returncode}): {said}")
        yield child
    finally:
        child.stop(stop)
