"""A run's worst lateness is its worst over the whole run. The summary's ``lateness_max_us`` was the max of
the ring of newest samples (65 536 a task): a real-time run longer than the ring — 66 s of the world's
1 kHz steps, 5.5 min of a 200 Hz estimator — reported a max that had forgotten its worst stall, the figure
``summary.json`` and ``bench/`` give for the run's timing. In lockstep with the injected clock: a task
declared first stalls once, at a drawn activation and for a drawn time under one period, so the task due
with it starts late by exactly that, then the run goes on past the ring."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.timing.clock import LockstepClock
from hil.timing.scheduler import PeriodicTask, Scheduler

PERIOD_S = 0.001
RING = 65_536  # the scheduler's ring of lateness samples per task


@settings(max_examples=4, deadline=None)
@given(stall_at=st.integers(0, 2_000), stall_us=st.integers(1, 999))
def test_the_worst_lateness_is_kept_after_the_ring_has_turned(stall_at, stall_us):
    clock = LockstepClock()
    calls = 0

    def stalls(_due: float) -> None:
        nonlocal calls
        calls += 1
        if calls == stall_at + 1:
            clock.advance(stall_us * 1e-6)  # under a period: late, not an overrun

    staller = PeriodicTask("estimator", PERIOD_S, stalls)
    world = PeriodicTask("world", PERIOD_S, lambda _due: None)
    Scheduler(clock, [staller, world]).run(until=(RING + 2_100) * PERIOD_S)
    assert world.stats.runs > RING + stall_at and world.stats.overruns == 0
    summary = world.stats.summary()
    assert summary["lateness_max_us"] == pytest.approx(stall_us, abs=1e-3), summary
    assert staller.stats.summary()["lateness_max_us"] == 0.0


def test_no_run_no_max():
    task = PeriodicTask("control", 0.02, lambda _due: None)
    summary = task.stats.summary()
    assert summary["runs"] == 0 and summary["lateness_max_us"] != summary["lateness_max_us"]  # NaN
