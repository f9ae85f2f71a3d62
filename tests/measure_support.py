"""Measuring a command: from outside (its exit status, peak resident memory and wall time), or in this
process (the peak of the memory Python traced while it ran)."""

from __future__ import annotations

import subprocess
import sys
import tracemalloc
from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")

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


def traced_peak(action: Callable[[], T]) -> tuple[T, int]:
    """``action()``'s result and the peak of the memory Python traced while it ran (bytes)."""
    tracemalloc.start()
    try:
        result = action()
        return result, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
