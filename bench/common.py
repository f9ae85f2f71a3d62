"""Shared pieces of the benchmarks: the result row and a timer."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass


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
