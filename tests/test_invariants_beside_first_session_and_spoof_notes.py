"""The fault campaigns' judge (:func:`hil.runtime.invariants.check_run`) beside two things it let pass: a
board fault that came between the host's first handshake and the session's first telemetry, and phone
spoofs of one reason counted by fewer readings than they sent. Each on a real lockstep run: the honest
record passes, and the same record hand-edited to hide the fault fails.

What broke: the first row of every run is written before the session's first telemetry came, so it shows
the board not live — and the judge took that for a view another fault had already taken: a hang or a
stall right after the handshake was listed unseen (masked), and a record that never told it passed,
though the host counts its stale bound from the session's start and tells the hang's reset by its
handshake. And a drop note credited as many spoofs as it counted readings, while each spoof sends three:
one spoof's three readings passed for three spoofs, two of them never counted.
"""

from __future__ import annotations

from typing import Any

from hypothesis import given
from hypothesis import strategies as st

from hil.montecarlo.runner import fault_bounds
from hil.runtime.invariants import InjectedFault, InvariantReport, check_run
from hil.runtime.record import RunRecorder
from hil.scenario import Scenario
from tests.fault_support import check_honest_end, faulted_run_settings, run_faults

SETTINGS = faulted_run_settings(6)
FIRST_HANDSHAKE_S = 0.1  # the first session's `connected` (cubesat-1u, lockstep): its first row 0.101


def _without(recorder: RunRecorder, *kinds: str, after: float = 0.0) -> RunRecorder:
    """``recorder`` with its journal's reports of ``kinds`` from ``after`` on taken out: a host that never
    told them."""
    s: dict[str, Any] = recorder.summary
    s["faults"] = [f for f in s["faults"] if not (f["kind"] in kinds and f["t"] >= after)]
    return recorder


def _judge(faults: list[InjectedFault], sc: Scenario, recorder: RunRecorder) -> InvariantReport:
    return check_run(faults, recorder, fault_bounds(sc))


# --------------------------------------------------------------------------- the first session's start
@SETTINGS
@given(
    kind=st.sampled_from(["hang", "stall", "brownout", "unplug"]),
    after_handshake_s=st.one_of(st.floats(0.0015, 0.0205), st.sampled_from([0.0015, 0.011, 0.02])),
)
def test_a_board_fault_before_the_first_telemetry_is_expected_of_the_host(kind, after_handshake_s):
    """A board fault at a drawn moment between the first handshake and the session's first telemetry:
    the honest run keeps every invariant, and the fault is expected (not listed unseen); with its
    reports taken out of the record, the judge fails it."""
    at = round(FIRST_HANDSHAKE_S + after_handshake_s, 4)
    params = {"duration_s": 0.6} if kind in ("stall", "unplug") else {}
    faults = [InjectedFault(kind, at, params)]
    sc, recorder = run_faults(faults)
    assert abs(recorder.first_event("connected")["t"] - FIRST_HANDSHAKE_S) < 1e-3
    report = check_honest_end(faults, sc, recorder)
    assert not report.unseen, report.unseen
    assert report.detection, "the fault's report was not credited to it"
    hidden = _without(recorder, "stale", "reset", "failsafe", "link_lost")
    assert _judge(faults, sc, hidden).violations["faults_detected"]


# --------------------------------------------------------------------------- spoofs and their drop notes
@SETTINGS
@given(
    spoof=st.sampled_from(["nan", "huge", "future", "past"]),
    gaps_s=st.lists(st.sampled_from([0.0, 0.01, 0.03, 0.05]), min_size=2, max_size=2),
    at=st.floats(2.5, 7.0),
)
def test_spoofs_of_one_reason_are_each_counted_by_their_readings(spoof, gaps_s, at):
    """Three spoofs of one reason close together: the honest run keeps every invariant; the record with
    only the first spoof's readings counted (its two notes: the first reading, then the other two) fails
    — two spoofs were never counted."""
    times = [round(at, 3), round(at + gaps_s[0], 3), round(at + gaps_s[0] + gaps_s[1], 3)]
    faults = [InjectedFault("phone_spoof", t, {"spoof": spoof}) for t in times]
    sc, recorder = run_faults(faults)
    check_honest_end(faults, sc, recorder)
    notes = [f for f in recorder.summary["faults"] if f["kind"] == "readings_dropped" and f["t"] >= at]
    assert sum(n["since_last"] for n in notes) == 9, notes
    first = dict(notes[0], since_last=1)
    rest = dict(notes[1], since_last=2)
    hidden = _without(recorder, "readings_dropped", after=at)
    hidden.summary["faults"] += [first, rest]
    assert _judge(faults, sc, hidden).violations["faults_detected"]
