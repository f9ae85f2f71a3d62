"""The phone beside its tested path, in a lockstep run of the real host (a hunt's findings):

1. **The ground station's phone rates after the estimator started afresh.** The live feed took the
   merger's accepted counts for the run's, but a fresh start (a pause over a second, a clock re-anchored)
   makes a new merger whose counts start at zero: the page drew rates of −600 Hz for a second and a silent
   magnetometer's age as 0 ms. The counts are now the run's (:attr:`Host.accepted_by_sensor`): they never
   go back, no rate is negative, and an age only falls when a sample of its sensor came.
2. **Drops held back by the record's rate limit.** Readings dropped within 0.1 s of their reason's last
   record were counted, but recorded only when a later drop of that reason came 0.1 s on: a burst of 500
   readings past the gyro's bound made one ``readings_dropped`` record, ``total 1``, and the log, the
   printed faults and ``events.jsonl`` never said more. What a window holds back is now recorded on the
   next control tick after it, and at the run's end.
3. **A phone clock running fast.** Stamps 0.9 s apart arriving 5 ms apart passed the guard (each within a
   second of the last) and the estimator integrated 0.9 s steps. Readings ahead of the host's clock by
   more than ``JUMP_S`` against the least-delayed one are now ``future``, and a stream of them re-anchors
   the clock as a jump.
"""

from __future__ import annotations

import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from observer_support import SilentObserver

from hil.estimation.admission import CLOCK_RATE_SLACK, JUMP_S, PhoneGuard, Verdict
from hil.estimation.sensors import SensorKind, SensorSample
from hil.gcs.info import LIVE_COLUMNS, PHONE_LABELS
from hil.gcs.live import LiveFeed
from hil.montecarlo.fault_plan import fault_options
from hil.runtime import RunOptions, run
from hil.runtime.invariants import InjectedFault
from hil.runtime.observer import Observers
from hil.runtime.record import RunRecorder
from tests.fault_support import short_scenario

GAP_AT_S, GAP_S = 5.0, 1.6  # a pause of the phone longer than the estimator's MAX_GAP_S (1 s)


class _Polled(SilentObserver):
    """Polls a live feed every tick (its rows with their live columns, as the page gets them) and keeps
    the host's run counts of accepted samples at each tick."""

    def __init__(self, feed: LiveFeed) -> None:
        self.feed = feed
        self.host = None
        self.rows: list[list] = []  # type: ignore[type-arg]
        self.columns: list[str] = []
        self.counts: list[dict[str, int]] = []

    def started(self, start) -> None:  # type: ignore[no-untyped-def]
        self.host = start.host
        self.columns = [*start.host.columns, *LIVE_COLUMNS]

    def tick(self, t: float) -> None:
        assert self.host is not None
        self.counts.append(self.host.accepted_by_sensor)
        self.rows += self.feed.poll().rows

    def finished(self, summary) -> None:  # type: ignore[no-untyped-def]
        self.rows += self.feed.poll().rows


def test_the_pages_phone_rates_and_ages_through_an_estimator_restart():
    sc = short_scenario()
    sc = sc.with_changes(
        fault_options=fault_options(
            (InjectedFault("phone_gap", GAP_AT_S, {"duration_s": GAP_S}),), sc.fault_options
        )
    )
    feed = LiveFeed()
    polled = _Polled(feed)
    recorder = RunRecorder(sc.n_units)
    run(sc, RunOptions(out_root=None, observer=Observers(recorder, feed, polled), rows_to_observer=True))
    assert any(e["kind"] == "estimator_restart" for e in recorder.events), "the gap restarted no estimator"
    for before, after in zip(polled.counts, polled.counts[1:], strict=False):
        assert all(after[k] >= before[k] for k in PHONE_LABELS), (before, after)
    col = {name: i for i, name in enumerate(polled.columns)}
    rows = polled.rows
    assert len(rows) > 200
    for k in PHONE_LABELS:
        rates = [r[col[f"phone_rate_{k}"]] for r in rows if r[col[f"phone_rate_{k}"]] is not None]
        assert rates and min(rates) >= 0.0, (k, min(rates))
        in_gap = [
            r[col[f"phone_age_ms_{k}"]]
            for r in rows
            if GAP_AT_S + 0.3 <= r[col["t"]] <= GAP_AT_S + GAP_S - 0.1
        ]
        assert in_gap and min(in_gap) >= 250.0, (k, min(in_gap))  # stale all through the gap, never "live"


class _Burst(SilentObserver):
    """At each drawn moment, hands the host ``count`` gyro readings past the gyro's bound (``out_of_range``)
    stamped on the phone's clock, as a burst of one datagram would arrive."""

    def __init__(self, plan: list[tuple[float, int]]) -> None:
        self.plan = sorted(plan)
        self.host = None
        self.sent = 0

    def started(self, start) -> None:  # type: ignore[no-untyped-def]
        self.host = start.host

    def tick(self, t: float) -> None:
        while self.plan and self.plan[0][0] <= t:
            _, count = self.plan.pop(0)
            samples = [SensorSample(t + 1e-4 * i, SensorKind.GYR, (41.0, 0.0, 0.0)) for i in range(count)]
            assert self.host is not None
            self.host.feed(samples, t)
            self.sent += count


@settings(max_examples=6, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.lists(
        st.tuples(st.one_of(st.floats(0.2, 9.7), st.just(9.66)), st.integers(1, 500)), min_size=1, max_size=4
    )
)
def test_every_dropped_reading_of_a_burst_is_in_the_record(plan):
    """Whatever the bursts and wherever they fall (the run's last tick among them), the ``readings_dropped``
    records of ``out_of_range`` add up to the admission's count, in ``events.jsonl`` and the journal alike."""
    sc = short_scenario()
    burst = _Burst(list(plan))
    recorder = RunRecorder(sc.n_units)
    run(sc, RunOptions(out_root=None, observer=Observers(recorder, burst), rows_to_observer=True))
    s = recorder.summary
    counted = s["phone_admission"]["dropped"]["out_of_range"]
    assert counted == burst.sent
    records = [
        e for e in recorder.events if e["kind"] == "readings_dropped" and e["reason"] == "out_of_range"
    ]
    assert sum(e["since_last"] for e in records) == counted
    assert records[-1]["total"] == counted
    journal = [f for f in s["faults"] if f["kind"] == "readings_dropped" and f["reason"] == "out_of_range"]
    assert sum(f["since_last"] for f in journal) == counted


@pytest.mark.parametrize("gain", [180.0, 10.0, 2.0, 1.3])
def test_a_phone_clock_running_fast_is_not_integrated(gain):
    """Stamps advancing ``gain`` × as fast as the host's clock, every one within ``JUMP_S`` of the last: no
    accepted reading leads the host's clock (since the clock's anchor) by more than ``JUMP_S`` and the
    reference's slack; the rest are ``future``, and a stream of them re-anchors the clock (a jump) — never
    accepted on and on, as if that much time had passed."""
    period = 0.005
    n = math.ceil(JUMP_S * 4 / ((gain - 1.0 - CLOCK_RATE_SLACK) * period)) + 40  # leads by 4 s and more
    guard = PhoneGuard()
    anchor = None
    for k in range(n):
        t, now = 100.0 + k * period * gain, k * period
        verdict = guard.admit(SensorSample(t, SensorKind.GYR, (0.0, 0.0, 0.0)), now)
        if anchor is None or verdict is Verdict.JUMP:
            anchor = (t, now)
        if verdict is not Verdict.DROP:
            lead = (t - anchor[0]) - (now - anchor[1])
            assert lead <= JUMP_S + CLOCK_RATE_SLACK * (now - anchor[1]) + 1e-9, (k, verdict, lead)
    assert guard.stats.jumps > 0 and guard.stats.dropped["future"] > 0


@given(
    drift_ppm=st.floats(-1000.0, 1000.0),
    delays=st.lists(st.floats(0.0, 0.9), min_size=50, max_size=400),
    offset=st.floats(-1e6, 1e6),
)
@settings(max_examples=200, deadline=None)
def test_a_phone_clock_as_phones_keep_it_is_never_judged_ahead(drift_ppm, delays, offset):
    """A phone's clock off the host's by any offset, drifting up to 1000 ppm, its readings delayed by the
    network anywhere from 0 to 0.9 s (in any order of delays): every reading is accepted."""
    period = 0.005
    guard = PhoneGuard()
    pairs = []
    for k, delay in enumerate(delays):
        made = k * period
        pairs.append((offset + made * (1.0 + drift_ppm * 1e-6), made + delay))
    pairs.sort(key=lambda p: p[1])  # as they arrive
    latest = -math.inf
    for stamp, now in pairs:
        if stamp <= latest:
            continue  # overtaken by a later one: out of order, another reason
        latest = stamp
        assert guard.admit(SensorSample(stamp, SensorKind.GYR, (0.0, 0.0, 0.0)), now) is Verdict.ACCEPT
    assert guard.stats.dropped["future"] == 0


def test_a_faults_printed_details_keep_their_figures():
    """The printed summary's fault line gives a detail's figures as ``summary.json`` has them (to four
    significant figures): a 0.25 s bound printed 0.2, beside a 0.321 s batch period printed 0.3."""
    from hil.cli.run import fault_lines

    fault = {"t": 2.413, "kind": "phone_batched", "period_s": 0.321, "stale_after_s": 0.25, "big": 1e160}
    (line,) = fault_lines({"faults": [fault]})
    assert "period_s 0.321  stale_after_s 0.25  big 1e+160" in line, line
