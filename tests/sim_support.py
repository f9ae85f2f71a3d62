"""``firmware-sim`` as a process of its own on a real pty, for the fault campaigns that kill, restart and
stop it (tests/test_pty_fault_campaign.py, tests/test_tool_fault_campaigns.py)."""

from __future__ import annotations

import contextlib
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


class Sim:
    """``firmware-sim`` in its own process on a pty (``--link`` kept pointing at it; ``path`` the pty it
    printed); its log in a file beside the test's."""

    def __init__(self, tmp: Path, link: Path, *options: str) -> None:
        self.log = tmp / f"firmware-sim-{time.monotonic_ns()}.log"
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "firmware_sim", "--link", str(link), *options],
            stdout=subprocess.PIPE,
            stderr=self.log.open("w"),
            text=True,
            cwd=ROOT,
        )
        assert self.proc.stdout is not None
        self.path = self.proc.stdout.readline().strip()
        if not self.path.startswith("/dev/"):
            self.kill()
            raise RuntimeError(f"firmware-sim did not start: {self.path} {self.log.read_text()[-2000:]}")

    @property
    def alive(self) -> bool:
        return self.proc.poll() is None

    def kill(self) -> None:
        if self.proc.poll() is None:
            # SIGKILL first: a stopped board dies without running again (SIGCONT first let it answer what
            # its pty held — a Hello sent while it was stopped — before it died); SIGCONT then only wakes
            # it to be reaped at once
            self.proc.kill()
            self.proc.send_signal(signal.SIGCONT)
        self.proc.wait(timeout=10)

    def pause(self, seconds: float) -> None:
        """SIGSTOP for ``seconds``, then SIGCONT (a board whose process is not run: its pty stays)."""
        self.proc.send_signal(signal.SIGSTOP)
        try:
            time.sleep(seconds)
        finally:
            self.proc.send_signal(signal.SIGCONT)


@contextlib.contextmanager
def sims(tmp: Path) -> Iterator[list[Sim]]:
    """The boards a test starts, each killed on the way out."""
    started: list[Sim] = []
    try:
        yield started
    finally:
        for sim in started:
            sim.kill()
