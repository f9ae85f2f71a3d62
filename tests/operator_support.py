"""A ``python -m hil`` subprocess with a real pty for its stdin (the operator's terminal) and its output
read line by line as it comes: the calibration tests' operator and signal tests drive it."""

from __future__ import annotations

import os
import pty
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field


@dataclass
class Operated:
    """``python -m hil ARGV`` with a pty for stdin (the operator types into ``master``) and stdout read
    line by line (with the wall time each line arrived) by a thread."""

    argv: list[str]
    lines: list[tuple[float, str]] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.master, slave = pty.openpty()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "hil", *self.argv],
            stdin=slave,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        os.close(slave)
        self._readers = [
            threading.Thread(target=self._read, daemon=True),
            threading.Thread(target=self._read_errors, daemon=True),
        ]
        for reader in self._readers:
            reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append((time.monotonic(), line.rstrip("\n")))

    def _read_errors(self) -> None:
        assert self.proc.stderr is not None
        self.errors += self.proc.stderr

    def wait_for(self, text: str, timeout: float = 60.0) -> float:
        """The wall time the first stdout line containing ``text`` arrived."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            hit = next((t for t, line in self.lines if text in line), None)
            if hit is not None:
                return hit
            assert self.proc.poll() is None, f"exited {self.proc.returncode}: {self.finish()}"
            time.sleep(0.05)
        raise AssertionError(f"no {text!r} within {timeout} s: {self.stdout}")

    def type(self, keys: bytes) -> None:
        os.write(self.master, keys)

    def finish(self, timeout: float = 60.0) -> tuple[int, str]:
        try:
            self.proc.wait(timeout=timeout)
        finally:
            if self.proc.poll() is None:
                self.proc.kill()
                self.proc.wait()
            os.close(self.master)
        for reader in self._readers:
            reader.join(timeout=5.0)
        return self.proc.returncode, "".join(self.errors)

    @property
    def stdout(self) -> str:
        return "\n".join(line for _, line in self.lines)
