"""A run's exit at its very end, beside the path (the campaigns' judge caught the host saying otherwise).

1. **A board lost as the run ended, its final Disarm failing with it** (a brown-out 10 ms before the end, the
   cable out 10 ms after): the exit said ``incomplete: the run completed, but the board is not confirmed
   disarmed`` while ``summary.json``'s ``lost`` said the board was lost. The loss is said first now:
   ``lost: board link lost as the run ended …`` (status 3), the failed Disarm in ``final_disarm``.
2. **The operator's Arm a few ms before the end** (a Disarm just before the end moves it by its suspension):
   the run said ``completed`` with the board DISARMED in its last row, the Arm not yet carried out. A run
   whose time runs out with the board not live and ARMED says so now: ``incomplete: the run's time ran out
   with the board DISARMED, not armed (the operator's Arm at t=… not yet carried out)``.

Each at drawn moments about the run's end; the judge (every invariant) passes each record.
"""

from __future__ import annotations

from fault_support import check_honest_end, run_faults
from hypothesis import example, given, settings
from hypothesis import strategies as st

from hil.runtime.invariants import InjectedFault
from hil.runtime.summary import RAN_OUT_UNARMED

END_S = 9.7  # the short scenario's end: its slew's start and duration (tests/fault_support.py)


@settings(max_examples=4, deadline=None)
@given(before=st.floats(0.005, 0.03), after=st.floats(0.005, 0.03))
@example(before=0.01, after=0.012)
def test_a_board_lost_as_the_run_ends_is_said_lost_not_only_unconfirmed_disarmed(before, after):
    faults = [
        InjectedFault("brownout", round(END_S - before, 3)),
        InjectedFault("unplug", round(END_S + after, 3), {"duration_s": 0.6}),
    ]
    sc, recorder = run_faults(faults)
    check_honest_end(faults, sc, recorder)
    s = recorder.summary
    if s.get("lost"):
        assert s["exit"] == f"lost: {s['lost']}", s["exit"]
    assert s["exit"] != "completed"


@settings(max_examples=4, deadline=None)
@given(disarm_before=st.floats(0.002, 0.02), arm_after_s=st.floats(0.3, 1.5))
@example(disarm_before=0.003, arm_after_s=1.136)
def test_an_arm_just_before_the_moved_end_is_no_completed_run_with_the_board_disarmed(
    disarm_before, arm_after_s
):
    disarm_at = round(END_S - disarm_before, 3)
    faults = [
        InjectedFault("disarm", disarm_at),
        InjectedFault("arm", round(disarm_at + arm_after_s, 3), {"after_disarm_s": arm_after_s}),
    ]
    sc, recorder = run_faults(faults)
    check_honest_end(faults, sc, recorder)  # completed only live and ARMED at the end
    s = recorder.summary
    rows = recorder.rows()
    if rows["board_state"][-1] != 2:
        said = f"{RAN_OUT_UNARMED} DISARMED, not armed (the operator's Arm at t="
        assert s["exit"].startswith(said), s["exit"]
