"""An activation that ends exactly on one of its task's later deadlines — a lockstep step that waited, on
the run's clock, to the next control instant (a blocking command to the board in lockstep jumps the clock
to what it waits for) — has missed the deadlines before that one, not that one: it runs at once, on time,
and only the deadlines strictly before count as overruns. The scheduler skipped it as well, or not, as the
rounding of ``now - deadline`` fell (3 × 10 ms skipped three, 2 × 10 ms one), counting one overrun too
many: a control instant lost and a run's timing figures wrong at whole-period waits, the very waits a
lockstep run makes. The waits are drawn: length in periods, the activation that waits, the origin, and
whether the wait ends on the deadline as the scheduler computes it or as ``due + n · period`` (the same
nanosecond, other last bits)."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.timing.clock import LockstepClock
from hil.timing.scheduler import PeriodicTask, Scheduler

PERIODS_S = (1 / 490, 0.001, 0.005, 0.01, 1 / 30, 0.02, 0.05)


@settings(max_examples=300, deadline=None)
@given(
    period_s=st.sampled_from(PERIODS_S),
    origin=st.floats(0.0, 5_000.0),
    waits_at=st.integers(0, 20),
    periods=st.integers(1, 150),
    as_scheduled=st.booleans(),
)
def test_a_wait_that_ends_on_a_deadline_runs_that_activation_on_time(
    period_s, origin, waits_at, periods, as_scheduled
):
    clock = LockstepClock(start=origin)
    ran: list[tuple[float, float]] = []  # (deadline, clock when it started)

    def step(due: float) -> None:
        ran.append((due, clock.now()))
        if len(ran) == waits_at + 1:  # this activation waits `periods` periods on the run's clock
            k = waits_at + periods
            clock.sleep_until(origin + k * period_s if as_scheduled else due + periods * period_s)

    task = PeriodicTask("control", period_s, step)
    Scheduler(clock, [task], origin=origin).run(until=origin + (waits_at + periods + 3) * period_s)
    after_wait = ran[waits_at + 1]
    assert round(after_wait[0] * 1e9) == round((origin + (waits_at + periods) * period_s) * 1e9), ran[
        waits_at:
    ]
    assert task.stats.overruns == periods - 1
    assert task.stats.summary()["lateness_max_us"] < 1e-3  # every activation ran at its deadline's ns
    assert [due for due, _ in ran] == sorted(due for due, _ in ran)


@pytest.mark.parametrize(
    ("wait_to", "expected_next", "overruns"), [(0.03, 0.03, 0), (0.0305, 0.04, 1), (0.05, 0.05, 2)]
)
def test_a_wait_to_a_deadline_skips_only_those_before_it(wait_to, expected_next, overruns):
    """The documented rule either side of the boundary: due at 20 ms, waited to 30 ms (its next deadline):
    nothing missed; to 30.5 ms: the 30 ms one missed, the next at 40 ms; to 50 ms: two missed."""
    clock = LockstepClock()
    ran: list[float] = []

    def step(due: float) -> None:
        ran.append(due)
        if len(ran) == 3:
            clock.sleep_until(wait_to)

    task = PeriodicTask("control", 0.01, step)
    Scheduler(clock, [task]).run(until=0.1)
    assert abs(ran[3] - expected_next) < 1e-12 and task.stats.overruns == overruns, ran
