"""The fault campaigns' judge (:func:`hil.runtime.invariants.check_run`) beside a board that resets while
the host already cannot see it: a hang or a brown-out that lands inside a stall, or inside heavy byte
damage, after the host's view has gone stale. Its silence is hidden by the one already on, but its reset
is not: the board tells its reset's cause in its first frames once the link carries again, and the honest
host reports it (``reset`` WATCHDOG or BROWN_OUT in the journal).

What broke: such a fault was listed unseen ("masked") and nothing at all was expected of it — a host that
never told the board had reset (a watchdog that fired unreported) passed the judge. Each case on a real
lockstep run: the honest record passes and credits the reset to the fault; the same record with the
reset taken out fails.
"""

from __future__ import annotations

from typing import Any

from hypothesis import example, given
from hypothesis import strategies as st

from hil.montecarlo.runner import fault_bounds
from hil.runtime.invariants import InjectedFault, check_run
from hil.runtime.record import RunRecorder
from tests.fault_support import check_honest_end, faulted_run_settings, run_faults

SETTINGS = faulted_run_settings(8)
STALE_SEEN_S = 0.3  # a stall's or heavy noise's start → the host's view stale (0.25 s bound, a tick more)


def _without_resets(recorder: RunRecorder, after: float) -> RunRecorder:
    """``recorder`` with its journal's resets from ``after`` on taken out: a host that never told them."""
    s: dict[str, Any] = recorder.summary
    s["faults"] = [f for f in s["faults"] if not (f["kind"] == "reset" and f["t"] >= after)]
    return recorder


@SETTINGS
@given(
    kind=st.sampled_from(["hang", "brownout"]),
    blind=st.sampled_from(["stall", "noise"]),
    blind_at=st.floats(2.0, 6.5),
    into_s=st.floats(STALE_SEEN_S, 0.9),
)
@example(kind="hang", blind="stall", blind_at=5.0, into_s=0.4)
@example(kind="brownout", blind="noise", blind_at=5.0, into_s=0.5)
def test_a_reset_inside_a_stale_view_is_still_due_its_report(kind, blind, blind_at, into_s):
    """A stall (or noise damaging 30 % of the bytes) of 1 s at a drawn moment over the warm-up, the slew
    and the hold, and a hang or a brown-out drawn inside it once the host's view is stale: the honest run
    keeps every invariant and its reset is credited to the fault; with the reset hidden, it fails."""
    at = round(blind_at, 3)
    params: dict[str, Any] = {"duration_s": 1.0}
    if blind == "noise":
        params["corrupt"] = 0.3
    faults = [InjectedFault(blind, at, params), InjectedFault(kind, round(at + into_s, 3))]
    sc, recorder = run_faults(faults)
    report = check_honest_end(faults, sc, recorder)
    assert any(k == kind for k, _ in report.detection), (report.detection, report.unseen)
    hidden = _without_resets(recorder, after=at)
    assert check_run(faults, hidden, fault_bounds(sc)).violations["faults_detected"]


@SETTINGS
@given(kind=st.sampled_from(["hang", "brownout"]), after_handshake_s=st.floats(0.0005, 0.0015))
@example(kind="hang", after_handshake_s=0.001)
def test_a_reset_before_the_first_row_but_after_the_handshake_is_still_due_its_report(
    kind, after_handshake_s
):
    """A hang or a brown-out just after the first handshake (0.1 s), before the run's first row: the
    run's first Arm goes unanswered (a hung board: 0.5 s of tries), so the first row comes only then —
    yet the board tells its reset once it boots, and the honest host reports it. Before, a fault before
    the first row was masked, and a record without that reset passed."""
    at = round(0.1 + after_handshake_s, 4)
    faults = [InjectedFault(kind, at)]
    sc, recorder = run_faults(faults)
    assert recorder.first_event("connected")["t"] <= at
    report = check_honest_end(faults, sc, recorder)
    assert any(k == kind for k, _ in report.detection), (report.detection, report.unseen)
    hidden = _without_resets(recorder, after=at)
    assert check_run(faults, hidden, fault_bounds(sc)).violations["faults_detected"]
