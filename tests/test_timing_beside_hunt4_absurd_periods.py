"""Task periods and offsets that parse but are absurd. A period under the scheduler's nanosecond (1e-12 s)
was taken: its deadlines share nanoseconds (the instant by which tasks due together are ordered), and a run
of one second would have been 10^12 activations — refused now, naming the task. A period or offset so far
(1e300 s) that its deadline in nanoseconds is no finite number raised ``OverflowError`` out of the
scheduler's heap after its first activation; such a deadline is simply never reached before the limit."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.timing.clock import LockstepClock
from hil.timing.scheduler import PeriodicTask, Scheduler
from protocol.errors import ConfigError


@settings(max_examples=50, deadline=None)
@given(period_s=st.floats(min_value=5e-324, max_value=9.9e-10))
def test_a_period_under_a_nanosecond_is_refused_naming_the_task(period_s):
    with pytest.raises(ConfigError, match="task 'world'.*1 ns"):
        PeriodicTask("world", period_s, lambda _due: None)


@settings(max_examples=200, deadline=None)
@given(
    period_s=st.floats(min_value=1e-2, max_value=1.7e308),
    offset_s=st.one_of(st.just(0.0), st.floats(min_value=0.0, max_value=1.7e308)),
)
def test_a_far_period_or_offset_runs_what_is_due_and_ends_at_the_limit(period_s, offset_s):
    clock = LockstepClock()
    far: list[float] = []
    near: list[float] = []
    tasks = [
        PeriodicTask("far", period_s, far.append, offset_s=offset_s),
        PeriodicTask("near", 0.1, near.append),
    ]
    Scheduler(clock, tasks).run(until=2.0)
    # the run ends at its limit, or at a deadline the scheduler still runs within its 1 ns of it (an offset
    # of 1e-9 s: 2.000000001 s), with that nanosecond's rounding
    assert clock.now() == pytest.approx(2.0, abs=2e-9) and len(near) == 21
    expected = 0 if offset_s > 2.0 + 1e-9 else math.floor((2.0 - offset_s) / period_s + 1e-9) + 1
    assert abs(len(far) - expected) <= 1 and all(t <= 2.0 + 1e-9 for t in far), (len(far), expected)
