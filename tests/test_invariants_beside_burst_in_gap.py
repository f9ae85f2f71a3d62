"""The fault campaigns' judge (:func:`hil.runtime.invariants.check_run`) beside a phone spoof inside a
phone gap: a ``burst`` spoof still sends its 200 plausible readings while the phone is otherwise silent,
the admission takes some of them, and the host's phone is fresh again — its gap is told the stale bound
after that burst, not after the gap's start.

What broke: the gap was due 0.31 s after it began whatever came in it. A random probe's burst 0.19 s into
a 0.6 s gap: the honest host told the gap at 0.46 s, and the judge failed the run.
"""

from __future__ import annotations

from hypothesis import example, given
from hypothesis import strategies as st

from hil.montecarlo.runner import fault_bounds
from hil.runtime.invariants import InjectedFault, check_run
from tests.fault_support import check_honest_end, faulted_run_settings, run_faults

SETTINGS = faulted_run_settings(8)


@SETTINGS
@given(
    gap_at=st.one_of(st.floats(0.5, 8.5), st.sampled_from([2.121, 3.662])),
    gap_s=st.sampled_from([0.4, 0.6, 1.0]),
    into=st.floats(0.05, 0.95),
)
@example(gap_at=3.662, gap_s=0.6, into=0.185 / 0.6)  # the probe's draw
def test_a_burst_in_a_phone_gap_moves_its_report_and_the_run_ends_honestly(gap_at, gap_s, into):
    """A burst spoof at a drawn moment inside a phone gap at a drawn moment of the run: the honest run
    keeps every invariant."""
    gap_at = round(gap_at, 3)
    faults = [
        InjectedFault("phone_gap", gap_at, {"duration_s": gap_s}),
        InjectedFault("phone_spoof", round(gap_at + into * gap_s, 3), {"spoof": "burst"}),
    ]
    sc, recorder = run_faults(faults)
    check_honest_end(faults, sc, recorder)


def test_a_gap_a_burst_moved_is_still_due_its_report():
    """The probe's draw, with the host's ``phone_gap`` report taken out of the record: the judge fails it
    (the report is due later, not excused)."""
    faults = [
        InjectedFault("phone_gap", 3.662, {"duration_s": 0.6}),
        InjectedFault("phone_spoof", 3.847, {"spoof": "burst"}),
    ]
    sc, recorder = run_faults(faults)
    check_honest_end(faults, sc, recorder)
    recorder.summary["faults"] = [f for f in recorder.summary["faults"] if f["kind"] != "phone_gap"]
    assert check_run(faults, recorder, fault_bounds(sc)).violations["faults_detected"]
