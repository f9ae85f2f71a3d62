"""Times that are not finite numbers of seconds, given to the clocks and the scheduler, are refused with a
ConfigError naming where — never kept, never a hang, never Python's own error out of ``time.sleep``.

A lockstep clock told NaN kept it for ever (each comparison with NaN false: no deadline ever past, every
later time stamp NaN) and told ``inf`` (a wait with nothing to wake it: a lockstep ``BoardClient`` waiting
without a timeout on an idle link) jumped past every deadline; the wall clock raised ``OverflowError`` /
``ValueError`` from ``time.sleep``; a scheduler run until NaN never ended (no deadline is "after" NaN); a
clock that said NaN ran every task on, late by 0, with no overrun counted."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.timing.clock import LockstepClock, WallClock
from hil.timing.scheduler import PeriodicTask, Scheduler
from protocol.errors import ConfigError

NON_FINITE = (math.nan, math.inf, -math.inf)


@pytest.mark.parametrize("bad", NON_FINITE)
@pytest.mark.parametrize("call", ["advance", "set", "sleep_until"])
def test_a_lockstep_clock_refuses_a_time_that_is_not_finite_and_keeps_its_own(bad, call):
    clock = LockstepClock(start=12.5)
    with pytest.raises(ConfigError, match=f"LockstepClock.{call}"):
        getattr(clock, call)(bad)
    assert clock.now() == 12.5


@pytest.mark.parametrize("bad", NON_FINITE)
def test_a_lockstep_clock_cannot_start_at_a_time_that_is_not_finite(bad):
    with pytest.raises(ConfigError, match="LockstepClock"):
        LockstepClock(start=bad)


def test_a_lockstep_clock_moved_backwards_is_a_config_error_still_a_value_error():
    clock = LockstepClock(start=1.0)
    with pytest.raises(ConfigError, match="backwards"):
        clock.advance(-1e-9)
    with pytest.raises(ValueError, match="backwards"):
        clock.set(0.5)


@pytest.mark.parametrize("bad", (math.nan, math.inf, 1e300 * 1e300))
def test_the_wall_clock_refuses_to_sleep_until_a_time_that_is_not_finite(bad):
    clock = WallClock()
    with pytest.raises(ConfigError, match="WallClock.sleep_until"):
        clock.sleep_until(bad)
    clock.sleep_until(-1e300)  # long past: returns at once


def test_a_run_until_nan_is_refused_not_run_for_ever():
    clock = LockstepClock()
    sched: Scheduler

    def step(due: float) -> None:
        if due >= 1.0:  # the old scheduler ran on past any limit: stop it here so the test ends
            sched.stop()

    sched = Scheduler(clock, [PeriodicTask("control", 0.01, step)])
    with pytest.raises(ConfigError, match="Scheduler.run"):
        sched.run(until=math.nan)
    assert clock.now() == 0.0


class _Drifting:
    """A clock (the :class:`~hil.timing.clock.Clock` protocol) that, from its ``fail_at``-th read on, says
    ``bad``: a time source whose arithmetic broke."""

    def __init__(self, fail_at: int, bad: float) -> None:
        self.inner = LockstepClock()
        self.reads = 0
        self.fail_at = fail_at
        self.bad = bad

    def now(self) -> float:
        self.reads += 1
        return self.bad if self.reads >= self.fail_at else self.inner.now()

    def sleep_until(self, deadline: float) -> None:
        self.inner.sleep_until(deadline)


@settings(max_examples=60, deadline=None)
@given(fail_at=st.integers(1, 400), bad=st.sampled_from(NON_FINITE))
def test_a_clock_that_says_a_time_that_is_not_finite_stops_the_run_saying_so(fail_at, bad):
    clock = _Drifting(fail_at, bad)
    ran: list[float] = []
    tasks = [PeriodicTask("world", 0.001, ran.append), PeriodicTask("control", 0.02, lambda _due: None)]
    sched = Scheduler(clock, tasks, origin=0.0)
    with pytest.raises(ConfigError, match="Scheduler.run.*finite"):
        sched.run(until=10.0)
    assert len(ran) < 400  # stopped at the bad read, not run on to the limit
