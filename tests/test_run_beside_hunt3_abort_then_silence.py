"""The operator's abort acknowledged by the board, then the link silent (a stall, a hang, noise that
corrupts every frame) before any telemetry shows the Disarm carried out — at a drawn moment in each phase.

The abort ended the run with ``the board acknowledged the Disarm, yet its telemetry still says ARMED 0.5 s
later``: the telemetry it read was the last one received *before* the acknowledgement, half a second old —
a board that obeyed, said to disobey on a stale value (and the way out, which takes the acknowledgement
for the board's state, sent no second Disarm beside that claim). Only telemetry received since the
acknowledgement is the board's word on it now: the exit says none came, and how old the last is.

Lockstep runs of the short scenario (tests/fault_support.py): the abort at ``at``, the silence 2-20 ms
later (after the acknowledgement, before the next telemetry).
"""

from __future__ import annotations

from fault_support import faulted_run_settings, run_faults
from hypothesis import example, given
from hypothesis import strategies as st

from hil.montecarlo.runner import fault_bounds
from hil.runtime.invariants import InjectedFault, check_run

SILENCES = {
    "stall": {"duration_s": 1.0},
    "hang": {},
    "noise": {"duration_s": 1.0, "corrupt": 1.0},
}


@faulted_run_settings(max_examples=6)
@given(
    at=st.floats(1.0, 9.0),
    after=st.floats(0.002, 0.02),
    silence=st.sampled_from(sorted(SILENCES)),
)
@example(at=6.0, after=0.005, silence="stall")  # the hold
@example(at=4.0, after=0.01, silence="hang")  # the slew
@example(at=2.6, after=0.015, silence="noise")  # the first warm-up's spin-up
def test_an_abort_acknowledged_then_unheard_never_says_the_board_still_armed(at, after, silence):
    t = round(at, 3)
    faults = [InjectedFault("abort", t), InjectedFault(silence, round(t + after, 3), SILENCES[silence])]
    sc, recorder = run_faults(faults)
    # every invariant of the campaigns (not check_honest_end's open-outage length: an abort ends the run in
    # the tick's operator step, before that tick's row — the outage is measured one tick past the last row)
    report = check_run(faults, recorder, fault_bounds(sc))
    assert report.ok, report.violations
    exit_ = recorder.summary["exit"]
    assert exit_.startswith("aborted: from the fault campaign (command 1: "), exit_
    if "still says ARMED" in exit_:  # only on telemetry received at least STATE_CONFIRM_S after the ack
        acked = [e for e in recorder.events if e["kind"] == "command" and e["status"] == "acked"]
        rows = recorder.rows()
        last_armed = rows["t"][(rows["board_state"] == 2) & (rows["board_link"] == 0)]
        assert acked and last_armed.size and last_armed[-1] >= acked[0]["t"] + 0.5, exit_
