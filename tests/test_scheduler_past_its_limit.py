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
    ran: list[tuple[str, float, float]] = []  # (task, deadline, clock when it ran), every task's
    controls = 0
    paused: list[float] = []

    def control(due: float) -> None:
        nonlocal controls
        ran.append(("control", due, clock.now()))
        controls += 1
        if controls == pause_tick + 1:
            paused.append(clock.now())
            clock.advance(pause_s)  # the process stopped inside this activation

    other = PeriodicTask("estimator", 0.005, lambda due: ran.append(("estimator", due, clock.now())))
    task = PeriodicTask("control", PERIOD_S, control)
    Scheduler(clock, [other, task]).run(until=UNTIL_S)
    woke = paused[0] + pause_s
    after = [r for r in ran if r[2] >= woke]
    if woke > UNTIL_S + PERIOD_S:  # woke past the limit by more than a period: nothing more ran
        assert after == [], (paused[0], woke, after)
    for _, due, at in after:  # woke before it: late activations run, none past a period beyond the limit
        assert due <= UNTIL_S + 1e-9 and at <= UNTIL_S + PERIOD_S + 1e-9
    assert all(due <= UNTIL_S + 1e-9 for _, due, _ in ran)


def test_in_lockstep_every_activation_due_by_the_limit_runs():
    """No pause: each deadline up to the limit runs, the last one at the limit itself."""
    clock = LockstepClock()
    task = PeriodicTask("control", PERIOD_S, lambda due: None)
    Scheduler(clock, [task]).run(until=UNTIL_S)
    assert task.stats.runs == round(UNTIL_S / PERIOD_S) + 1 and clock.now() == UNTIL_S
