"""A phone whose clock runs slow against the host's (a hunt's finding): stamps advancing 0.5 s per second
of the host's passed the guard — each reading in order, none ahead — and the estimator integrated the
rotation at half its rate while the phone counted as fresh. The guard now judges the least
host-minus-stamp offset of each :data:`~hil.estimation.admission.SLOW_WINDOW_S` window: grown by more than
:data:`~hil.estimation.admission.CLOCK_RATE_SLACK` of the host's time in
:data:`~hil.estimation.admission.SLOW_WINDOWS` windows in a row, the clock runs slow and its readings are
``slow_clock`` (the phone then goes stale: its gap's cause is ``phone_clock_slow``). A network that stalls
and flushes, a clock that paused once, and a phone clock's real drift are never judged slow."""

from __future__ import annotations

import random

from hypothesis import given, settings
from hypothesis import strategies as st

from hil.estimation.admission import SLOW_WINDOW_S, SLOW_WINDOWS, PhoneGuard, Verdict
from hil.estimation.sensors import SensorKind, SensorSample
from hil.runtime.faults import FaultJournal
from hil.runtime.phone_clock import PhoneClock
from hil.runtime.runlog import EventLog

PERIOD_S = 0.005  # a 200 Hz gyroscope
STILL = (0.0, 0.0, 0.0)


def _admit(guard: PhoneGuard, pairs: list[tuple[float, float]]) -> list[Verdict]:
    """Each ``(stamp, host time it came)`` through ``guard``, in the order they came."""
    return [guard.admit(SensorSample(t, SensorKind.GYR, STILL), now) for t, now in pairs]


def _reasons(guard: PhoneGuard, pairs: list[tuple[float, float]]) -> list[str | None]:
    """Why each reading of :func:`_admit`'s was dropped (None: it was not)."""
    reasons = []
    for pair in pairs:
        [verdict] = _admit(guard, [pair])
        reasons.append(guard.last_reason if verdict is Verdict.DROP else None)
    return reasons


@settings(max_examples=40, deadline=None, derandomize=True)
@given(rate=st.floats(0.2, 0.85), jitter_s=st.floats(0.0, 0.05), seed=st.integers(0, 2**16))
def test_a_clock_running_slow_is_refused_within_a_few_windows_and_from_then_on(rate, jitter_s, seed):
    """Stamps advancing ``rate`` × the host's clock, each reading delayed by up to ``jitter_s``: within
    :data:`SLOW_WINDOWS` + 2 windows of host time the readings are ``slow_clock``, and every one after —
    the phone time the estimator integrated at most that many windows' worth at ``rate``."""
    draw = random.Random(seed)
    pairs = [(50.0 + rate * k * PERIOD_S, k * PERIOD_S + draw.uniform(0.0, jitter_s)) for k in range(4000)]
    pairs.sort(key=lambda p: p[1])
    guard = PhoneGuard()
    reasons = _reasons(guard, pairs)
    judged_by = (SLOW_WINDOWS + 2) * SLOW_WINDOW_S + jitter_s
    first = reasons.index("slow_clock")
    assert pairs[first][1] <= judged_by, (first, pairs[first])
    assert set(reasons[first:]) <= {"slow_clock", "out_of_order"}  # jitter's reorders are theirs
    accepted = [t for (t, _), why in zip(pairs, reasons, strict=True) if why is None]
    assert max(accepted) - min(accepted) <= rate * judged_by + 1e-9


@settings(max_examples=40, deadline=None, derandomize=True)
@given(
    drift_ppm=st.floats(-1000.0, 1000.0),
    stalls=st.lists(st.tuples(st.floats(0.2, 18.0), st.floats(0.05, 2.0)), max_size=6),
    jitter_s=st.floats(0.0, 0.05),
    seed=st.integers(0, 2**16),
)
def test_a_network_that_stalls_and_flushes_never_makes_a_clock_slow(drift_ppm, stalls, jitter_s, seed):
    """A phone's clock as phones keep it (any drift up to 1000 ppm), its readings held by the network in
    stalls of up to 2 s and then delivered at once, and jittered: every reading in order is accepted. (A
    stream whose very first second is such a backlog is one clock jump: the module docstring.)"""
    draw = random.Random(seed)
    pairs = []
    for k in range(int(20.0 / PERIOD_S)):
        made = k * PERIOD_S
        came = made + draw.uniform(0.0, jitter_s)
        for start, length in stalls:
            if start <= came < start + length:
                came = start + length  # held until the stall ends, then flushed
        pairs.append((7.0 + made * (1.0 + drift_ppm * 1e-6), came))
    pairs.sort(key=lambda p: p[1])
    latest, in_order = -1.0, []
    for stamp, now in pairs:
        if stamp > latest:  # a reading overtaken by a later one is out of order: another reason
            latest = stamp
            in_order.append((stamp, now))
    guard = PhoneGuard()
    assert set(_admit(guard, in_order)) == {Verdict.ACCEPT}
    assert guard.stats.dropped["slow_clock"] == 0 and not guard.slow


def test_a_clock_that_paused_once_is_taken_as_it_is():
    """A phone whose stamps stopped for 5 s (the app asleep) and went on from where they were: its offset
    to the host's clock grew once, not window after window — every reading accepted."""
    pairs = [(k * PERIOD_S, k * PERIOD_S) for k in range(1000)]  # 5 s
    pairs += [(5.0 + k * PERIOD_S, 10.0 + k * PERIOD_S) for k in range(2000)]  # 10 s on, 5 s behind
    guard = PhoneGuard()
    assert set(_admit(guard, pairs)) == {Verdict.ACCEPT}


def test_a_clock_that_stops_running_slow_is_taken_again():
    """Slow for 8 s, then at the host's rate: refused while slow, taken again from the first window whose
    least offset did not grow."""
    pairs = [(0.5 * k * PERIOD_S, k * PERIOD_S) for k in range(1600)]  # 8 s at half rate
    pairs += [(4.0 + k * PERIOD_S, 8.0 + k * PERIOD_S) for k in range(1, 1200)]  # then 6 s at full rate
    guard = PhoneGuard()
    verdicts = _admit(guard, pairs)
    assert Verdict.DROP in verdicts[:1600]
    assert set(verdicts[1600 + int(3 * SLOW_WINDOW_S / PERIOD_S) :]) == {Verdict.ACCEPT}


def test_a_phone_gap_of_a_slow_clock_says_so():
    """The host's record of the gap a slow clock makes names it: ``phone_clock_slow``, and why."""
    journal = FaultJournal()
    clock = PhoneClock(journal, EventLog(None), stale_after_s=0.25)
    for k in range(2000):
        now = k * PERIOD_S
        clock.admit(SensorSample(0.5 * now, SensorKind.GYR, STILL), now)
        clock.admit(SensorSample(0.5 * now + 1e-4, SensorKind.ACC, (0.0, 0.0, 9.8)), now)
        if k % 10 == 0:
            clock.freshness(now, clock.guard.stats.accepted)
    [gap] = [f for f in journal.faults if f["kind"] == "phone_gap"]
    assert "runs slow" in gap["why"], gap
    assert journal.phone_out is not None and "phone_clock_slow" in journal.phone_out.causes
