"""The operator's Disarm and Arm landing in one control tick (a ground station's two clicks queued for the
same tick, a campaign's Disarm drawn with ``arm_after_s`` 0), at a drawn moment in every phase.

The board carries them out in the order sent: ARMED → DISARMED → ARMED. The host's watch took the
DISARMED for "a Disarm the host no longer meant (one retried late)": a ``disarmed`` fault in the journal,
an ``unasked_disarm`` record, a recovery with an outage — and on the run's last tick the exit said
``lost: board lost at t=9.701 s for 0.0 s (disarmed): not back when the run ended`` (status 3) for a board
that was never lost. Now the DISARMED that the operator's own Disarm makes is no fault; the run's record
and every invariant of the campaigns hold (tests/fault_support.py).

Lockstep runs of the short scenario (its slew from ~3.7 s, its end at 9.7 s), the commands through
:class:`hil.runtime.operator.ScheduledOperator`, the path the ground station's and a campaign's take.
"""

from __future__ import annotations

from fault_support import check_honest_end, faulted_run_settings, run_faults
from hypothesis import example, given
from hypothesis import strategies as st

from hil.cli.run import exit_status
from hil.runtime.invariants import InjectedFault

END_S = 9.7  # the short scenario's end: its slew's start and duration (tests/fault_support.py)


@faulted_run_settings(max_examples=6)
@given(moment=st.floats(0.2, END_S - 0.005))
@example(moment=6.0)  # the hold
@example(moment=END_S - 0.01)  # the run's last tick: it said "lost ... for 0.0 s"
@example(moment=2.5)  # the first warm-up's spin-up
def test_a_disarm_and_an_arm_in_one_tick_are_no_fault_of_the_board(moment):
    t = round(moment, 3)
    faults = [
        InjectedFault("disarm", t, {"arm_after_s": 0.0}),
        InjectedFault("arm", t, {"after_disarm_s": 0.0}),
    ]
    sc, recorder = run_faults(faults)
    check_honest_end(faults, sc, recorder)
    s = recorder.summary
    kinds = [e["kind"] for e in recorder.events]
    assert "unasked_disarm" not in kinds, [e for e in recorder.events if e["kind"] == "unasked_disarm"]
    assert [f for f in s["faults"] if f["kind"] == "disarmed"] == [], s["faults"]
    assert not s["lost"] and not s["exit"].startswith("lost"), s["exit"]
    # the Disarm is superseded by the Arm (protocol.reliable), carried out or not: never "failed", which
    # the ground station reads as "no answer from the board"
    assert [o["command"] for o in s["operator"]] == ["disarm", "arm"]
    assert s["operator"][0]["status"] in ("superseded", "acked"), s["operator"][0]
    assert s["operator"][1]["status"] in ("sent", "acked")  # the Arm's answer may come after the run's end
    if s["exit"] != "completed":  # only a run whose time ran out before the Arm showed may say otherwise
        assert exit_status(s) == 1, s["exit"]
