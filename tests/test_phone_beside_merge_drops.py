"""Readings the admission accepted and the merger then dropped (a reordered UDP stream; a phone clock
stepped back a little by NTP) went to no count of ``summary.json``: the admission said "accepted 3000,
dropped 0" while the merger dropped 250 gyro readings as out of order, one log line per sensor. Now a
reading older than its sensor's last is dropped by the admission with its own reason (``out_of_order``),
and the merger's own counts are in ``summary.json`` (``phone_merge``): whatever arrives, every reading fed
is accepted or dropped by reason, and nothing the admission accepted is dropped by the merger.

Through a real UDP socket and the real receiver into a lockstep host beside its world's phone (the
pattern of tests/test_hostile_readings.py)."""

from __future__ import annotations

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.link.sources.phone_udp import PhoneUdpReceiver
from hil.runtime import RunOptions, run
from hil.runtime.observer import Observers
from hil.runtime.record import RunRecorder
from hil.scenario import load_scenario
from tests.test_hostile_readings import TYPES, Injector

behind = st.integers(1, 900_000_000)  # ns before the phone's clock: a late datagram, a small step back
late_reading = st.tuples(
    st.sampled_from(TYPES),
    behind.map(lambda ns: ("offset", -ns)),
    st.just([0.001, -0.002, 9.8]),
)
injection = st.tuples(st.floats(0.5, 3.5), st.lists(late_reading, min_size=1, max_size=10), st.integers(1, 5))


def _run(plan: list) -> tuple[dict, RunRecorder, Injector]:  # type: ignore[type-arg]
    sc = load_scenario("cubesat-1u")
    with PhoneUdpReceiver("udp://127.0.0.1:0") as receiver:
        recorder = RunRecorder(sc.n_units)
        injector = Injector(receiver, plan)
        result = run(
            sc,
            RunOptions(
                out_root=None, duration_s=3.0, observer=Observers(recorder, injector), rows_to_observer=True
            ),
        )
    return result.summary, recorder, injector


def _accounted(s: dict) -> None:  # type: ignore[type-arg]
    """Every reading fed is accepted or dropped by reason; what the admission accepted, the merger took."""
    admission, merge = s["phone_admission"], s["phone_merge"]
    assert admission["accepted"] + sum(admission["dropped"].values()) == s["phone_samples"]
    assert merge["dropped_total"] == 0, merge["dropped"]
    assert sum(merge["accepted"].values()) == admission["accepted"]


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(injection, min_size=1, max_size=3))
def test_late_readings_are_dropped_by_reason_and_the_merger_drops_nothing_unsaid(plan):
    s, _, injector = _run(list(plan))
    assert injector.handed > 0
    _accounted(s)


def test_a_late_reading_is_out_of_order_in_the_summary_and_the_record():
    """One gyro reading 50 ms behind the phone's clock, 20 times over: each dropped as ``out_of_order``,
    in ``phone_admission`` and in a ``readings_dropped`` record (before: accepted by the admission, dropped
    by the merger, in no count)."""
    late = [(TYPES[0], ("offset", -50_000_000), [0.001, 0.0, 0.0])]
    s, recorder, _ = _run([(1.0 + 0.1 * k, late, 1) for k in range(20)])
    _accounted(s)
    assert s["phone_admission"]["dropped"]["out_of_order"] >= 19
    dropped = [e for e in recorder.events if e["kind"] == "readings_dropped"]
    assert any(e["reason"] == "out_of_order" for e in dropped)
