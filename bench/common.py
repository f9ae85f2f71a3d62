"""Shared pieces of the benchmarks: the result row, a timer, and an atheris harness's fuzzing rate."""

from __future__ import annotations

import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class Result:
    """One figure. ``higher_is_better`` decides how the ratio against the peer is read."""

    bench: str
    name: str
    value: float
    unit: str
    peer: str = ""
    peer_value: float | None = None
    higher_is_better: bool = True
    note: str = ""

    @property
    def ratio(self) -> float | None:
        """Ours relative to the peer, >1 meaning better than the peer."""
        if self.peer_value is None or self.peer_value == 0 or self.value == 0:
            return None
        return self.value / self.peer_value if self.higher_is_better else self.peer_value / self.value


def rate(fn: Callable[[], object], min_time: float = 0.5, min_calls: int = 10) -> float:
    """Calls per second of ``fn``, measured over at least ``min_time`` seconds of wall time."""
    fn()  # warm up
    calls = 0
    start = time.perf_counter()
    elapsed = 0.0
    batch = 1
    while elapsed < min_time or calls < min_calls:
        for _ in range(batch):
            fn()
        calls += batch
        elapsed = time.perf_counter() - start
        batch = min(batch * 2, 10_000)
    return calls / elapsed


def fuzz_rate(harness: Path, runs: int, prefix: str) -> tuple[float, int]:
    """Inputs per second of an atheris harness (``python HARNESS -runs=N``), from two runs of different
    length so that process start-up and seed loading cancel out; and the inputs of the longer run (each
    one executed without an unhandled exception, or the harness fails and this raises)."""
    with tempfile.TemporaryDirectory(prefix=prefix) as work:
        t_short, n_short = _fuzz_once(harness, runs // 10, work)
        t_long, n_long = _fuzz_once(harness, runs, work)
    return (n_long - n_short) / max(t_long - t_short, 1e-9), n_long


def _fuzz_once(harness: Path, runs: int, work: str) -> tuple[float, int]:
    """Wall time of one harness process doing ``runs`` inputs, and the inputs libFuzzer reports."""
    start = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, str(harness), f"-runs={runs}", "-print_final_stats=1"],
        cwd=work, capture_output=True, text=True, timeout=900, check=False,
    )  # fmt: skip
    elapsed = time.perf_counter() - start
    out = proc.stdout + proc.stderr
    if proc.returncode != 0:
        raise RuntimeError(f"fuzz harness failed (exit {proc.returncode}):\n{out[-3000:]}")
    executed = re.search(r"stat::number_of_executed_units:\s*(\d+)", out)
    if not executed:
        raise RuntimeError(f"no libFuzzer final stats in the harness output:\n{out[-2000:]}")
    return elapsed, int(executed.group(1))
