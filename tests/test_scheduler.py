"""The periodic scheduler in lockstep time: deadlines, ordering, overruns, stopping."""

from __future__ import annotations

import pytest

from hil.timing.clock import LockstepClock
from hil.timing.scheduler import PeriodicTask, Scheduler
from protocol.errors import ConfigError


def test_tasks_run_at_their_rates_in_deadline_then_declaration_order():
    clock = LockstepClock()
    log: list[tuple[str, float]] = []
    fast = PeriodicTask("fast", 0.01, lambda t: log.append(("fast", t)))
    slow = PeriodicTask("slow", 1 / 30, lambda t: log.append(("slow", t)))
    sched = Scheduler(clock, [slow, fast])
    sched.run(until=1.0)
    assert fast.stats.runs == 101 and slow.stats.runs == 31
    assert [t for _, t in log] == sorted(t for _, t in log)
    # at t = 0 both are due: the one declared first runs first
    assert log[0] == ("slow", 0.0) and log[1] == ("fast", 0.0)
    assert clock.now() == 1.0
    assert fast.stats.overruns == 0 and fast.stats.percentile(99) == 0.0


def test_tasks_due_together_run_in_declaration_order_despite_rounding():
    """A 1 ms world task and a 30 ms control task meet every 30 ms; their float deadlines differ in the
    last bits (11 × 30 × 0.001 > 11 × 0.03), which must not let the control task run before the world
    it reads."""
    assert 330 * 0.001 > 11 * 0.03  # the rounding this test is about
    clock = LockstepClock(start=0.101)
    order: list[str] = []
    world = PeriodicTask("world", 0.001, lambda t: order.append("world"))
    control = PeriodicTask("control", 0.03, lambda t: order.append("control"))
    Scheduler(clock, [world, control]).run(until=0.101 + 3.0)
    assert control.stats.runs == 101 and world.stats.runs == 3001
    # the world of the same instant ran just before each control activation: 30 world runs apart
    starts = [k for k, name in enumerate(order) if name == "control"]
    assert [order[:k].count("world") for k in starts] == [1 + 30 * j for j in range(101)]


def test_deadlines_do_not_accumulate_rounding_error():
    clock = LockstepClock(start=12.5)
    seen: list[float] = []
    task = PeriodicTask("pulse", 1 / 490, seen.append)
    Scheduler(clock, [task]).run(until=12.5 + 200.0)
    assert len(seen) == 200 * 490 + 1
    assert seen[-1] == 12.5 + 98_000 * (1 / 490)
    # a naive t += period drifts measurably over the same run
    t = 12.5
    for _ in range(98_000):
        t += 1 / 490
    assert abs(t - seen[-1]) > 1e-12


def test_an_overrun_skips_the_missed_activations_and_counts_them():
    clock = LockstepClock()
    calls: list[float] = []

    def slow_step(t: float) -> None:
        calls.append(t)
        if len(calls) == 3:
            clock.advance(0.025)  # this activation took 2.5 periods

    task = PeriodicTask("control", 0.01, slow_step)
    Scheduler(clock, [task]).run(until=0.1)
    assert calls[:4] == [0.0, 0.01, 0.02, 0.05]
    assert task.stats.overruns == 2
    # the run after the skip starts on its own deadline, not late
    assert task.stats.summary()["lateness_max_us"] == 0.0


def test_stop_from_a_callback_ends_the_run():
    clock = LockstepClock()
    sched: Scheduler

    def cb(t: float) -> None:
        if t >= 0.5:
            sched.stop()

    sched = Scheduler(clock, [PeriodicTask("a", 0.1, cb, offset_s=0.05)])
    sched.run()
    assert sched.tasks[0].stats.runs == 6 and clock.now() == pytest.approx(0.55)


@pytest.mark.parametrize(
    "kwargs",
    [dict(period_s=0.0), dict(period_s=float("nan")), dict(period_s=-1.0), dict(period_s=0.1, offset_s=-1)],
)
def test_bad_task_parameters_are_config_errors_naming_the_task(kwargs):
    with pytest.raises(ConfigError, match="task 'x'"):
        PeriodicTask("x", callback=lambda t: None, **kwargs)


def test_duplicate_names_and_empty_schedules_are_refused():
    clock = LockstepClock()
    with pytest.raises(ConfigError):
        Scheduler(clock, [])
    with pytest.raises(ConfigError, match="unique"):
        Scheduler(clock, [PeriodicTask("a", 0.1, print), PeriodicTask("a", 0.2, print)])
