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
from pathlib import Path


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
        for line in self.proc.stderr:  # a line at a time, as it comes (wait_for_error)
            self.errors.append(line)

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

    def wait_for_error(self, text: str, timeout: float = 60.0) -> None:
        """Until a stderr line containing ``text`` has come."""
        end = time.monotonic() + timeout
        while not any(text in line for line in list(self.errors)):
            assert self.proc.poll() is None, (self.proc.returncode, self.errors)
            assert time.monotonic() < end, (text, self.errors)
            time.sleep(0.02)

    def wait_for_open(self, path: str, timeout: float = 60.0) -> None:
        """Until this process holds ``path`` open (a port: the pty a firmware-sim serves, its handshake
        begun)."""
        end = time.monotonic() + timeout
        fds = Path(f"/proc/{self.proc.pid}/fd")
        while time.monotonic() < end:
            assert self.proc.poll() is None, (self.proc.returncode, self.errors)
            for fd in list(fds.iterdir()) if fds.exists() else []:
                try:
                    if os.readlink(fd) == path:
                        return
                except OSError:  # closed meanwhile
                    continue
            time.sleep(0.02)
        raise AssertionError(f"{path} not opened within {timeout} s: {self.errors}")

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
