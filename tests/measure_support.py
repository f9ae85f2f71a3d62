"""Measuring a command from outside: its exit status, peak resident memory and wall time."""

from __future__ import annotations

import subprocess
import sys

MB = 1 << 20
MEASURE = """\
import resource, subprocess, sys, time
start = time.monotonic()
run = subprocess.run(sys.argv[1:], capture_output=True, text=True)
seconds = time.monotonic() - start
peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024
sys.stdout.write(f"{run.returncode} {peak} {seconds}\\n")
sys.stdout.write(run.stderr)
"""


def run_measured(*argv: str, timeout: float = 300.0) -> tuple[int, int, float, str]:
    """Run ``python -m hil ARGV`` in a fresh process that reports its child's exit status, peak resident
    memory (bytes) and wall time: the child is the only process that parent ever waited for, so its peak is
    the command's own. Returns (status, peak bytes, seconds, stderr)."""
    out = subprocess.run(
        [sys.executable, "-c", MEASURE, sys.executable, "-m", "hil", *argv],
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    head, _, stderr = out.stdout.partition("\n")
    status, peak, seconds = head.split()
    return int(status), int(peak), float(seconds), stderr
