"""An activation the scheduler finds past its limit by more than its period — its process paused across
the run's end, the clock seconds past ``until`` when it wakes — is not run: the run's time is up. It used
to run (its deadline was before the limit), and a host's control tick then acted on a run that had ended
(tests/test_host_paused_at_the_end.py). The clock is injected: a task's callback that moves it on is the
pause, drawn at every moment and for lengths either side of the limit."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from hil.timing.clock import LockstepClock
from hil.timing.scheduler import PeriodicTask, Scheduler

PERIOD_S = 0.02
UNTIL_S = 2.0


@settings(max_examples=200, deadline=None)
@given(pause_tick=st.integers(0, round(UNTIL_S / PERIOD_S)), pause_s=st.floats(0.0, 5.0))
def test_nothing_runs_once_a_paused_clock_is_past_the_limit(pause_tick, pause_s):
    clock = LockstepClock()
    ran: list[tuple[float, float]] = []  # (deadline, clock when it ran)

    def control(due: float) -> None:
        ran.append((due, clock.now()))
        if len(ran) == pause_tick + 1:
            clock.advance(pause_s)  # the process stopped inside this activation

    other = PeriodicTask("estimator", 0.005, lambda due: None)
    task = PeriodicTask("control", PERIOD_S, control)
    Scheduler(clock, [other, task]).run(until=UNTIL_S)
    paused_at = ran[pause_tick][1]
    woke = paused_at + pause_s
    after = ran[pause_tick + 1 :]
    if woke > UNTIL_S + PERIOD_S:  # woke past the limit by more than a period: nothing more ran
        assert after == [], (paused_at, woke, after)
    for due, at in after:
        assert due <= UNTIL_S + 1e-9 and at <= max(UNTIL_S, due) + PERIOD_S + 1e-9
    assert all(due <= UNTIL_S + 1e-9 for due, _ in ran)


def test_in_lockstep_every_activation_due_by_the_limit_runs():
    """No pause: each deadline up to the limit runs, the last one at the limit itself."""
    clock = LockstepClock()
    task = PeriodicTask("control", PERIOD_S, lambda due: None)
    Scheduler(clock, [task]).run(until=UNTIL_S)
    assert task.stats.runs == round(UNTIL_S / PERIOD_S) + 1 and clock.now() == UNTIL_S
