"""A phone that delivers its readings in batches spaced more than the stale bound (Sensor Logger's HTTP
Push period at 0.5 s; the host calls the phone stale after 0.25 s): every batch admitted, and every
interval between them was a phone gap — 93 phone_gap / warmup_restart / phone_back events, a warning
every 0.5 s, the slew never started, exit 1 after 47 s. Now, after a few such gaps, the run says once
that the phone is batched and what to set in the app (``phone_batched``), keeps one gap open across the
batches (never steering on a stale estimate, never restarting the warm-up per batch) and, the phone
staying batched, is lost within ``--recover-within`` saying why. A period under the bound is a phone that
streams: no gap at all.

The runtime's lockstep path, the world's phone held back and handed over in batches every ``period``
seconds of the host's clock (as the push receiver hands over what each push carried)."""

from __future__ import annotations

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from observer_support import SilentObserver

from hil.runtime import RunOptions, run
from hil.runtime.faults import STALE_AFTER_S
from hil.runtime.phone_cadence import BATCHED_GAPS
from hil.scenario import load_scenario


class Batches(SilentObserver):
    """Holds the world phone's readings and feeds them to the host every ``period`` s (host time)."""

    def __init__(self, period: float) -> None:
        self.period = period
        self.events: list[dict] = []  # type: ignore[type-arg]

    def started(self, start) -> None:  # type: ignore[no-untyped-def]
        host = start.host
        feed = host.feed
        held: list = []  # type: ignore[type-arg]
        last = [0.0]

        def batched(samples, now=None):  # type: ignore[no-untyped-def]
            held.extend(samples)
            if now is not None and now - last[0] >= self.period:
                last[0] = now
                batch = list(held)
                held.clear()
                feed(batch, now)

        host.feed = batched

    def event(self, record) -> None:  # type: ignore[no-untyped-def]
        self.events.append(record)


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.floats(STALE_AFTER_S + 0.08, 1.0))
def test_batches_spaced_beyond_the_stale_bound_are_said_once_and_lose_the_run_with_the_reason(period):
    batches = Batches(period)
    result = run(
        load_scenario("cubesat-1u"),
        RunOptions(out_root=None, duration_s=4.0, recover_within_s=4.0, observer=batches),
    )
    s = result.summary
    kinds = [e["kind"] for e in batches.events]
    told = [e for e in batches.events if e["kind"] == "phone_batched"]
    assert len(told) == 1, kinds
    assert abs(told[0]["period_s"] - period) < 0.05
    assert kinds.count("phone_gap") <= BATCHED_GAPS + 1, kinds.count("phone_gap")
    assert kinds.count("warmup_restart") <= BATCHED_GAPS + 1
    assert s["lost"] and "phone_batched" in s["lost"], s["lost"]
    assert told[0]["t"] < 4.0 * BATCHED_GAPS * period + 2.0


@settings(max_examples=4, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.floats(0.01, STALE_AFTER_S - 0.06))
def test_batches_within_the_stale_bound_are_a_streaming_phone(period):
    batches = Batches(period)
    result = run(load_scenario("cubesat-1u"), RunOptions(out_root=None, duration_s=4.0, observer=batches))
    s = result.summary
    assert s["exit"] == "completed", s["exit"]
    assert s["phone_gaps"] == 0 and not [e for e in batches.events if e["kind"] == "phone_batched"]
