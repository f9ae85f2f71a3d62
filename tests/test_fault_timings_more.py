"""Faults at moments the other fault tests do not use (a seeded probe over every phase of a short lockstep
run found what is pinned here): the operator's Disarm sent into a stalled link and the Arm that follows it,
at drawn moments of the warm-up, the spin-up, the slew's start, the slew and the hold; and single board
faults drawn over the whole run, each run checked for an honest end — a run that says ``completed`` ends
with the board live and ARMED, and its summary's counts agree with its events.

What broke: the Disarm, not answered in the stall, was retried with its sequence number once the link
carried again — after the operator's Arm, which the board had already carried out. The board ended
DISARMED (no setpoint moved a motor) while the host kept steering as though it were armed, opened no
outage, and the run said ``completed``. Now a newer Arm supersedes the pending Disarm (it is not sent
again: :meth:`protocol.reliable.ReliableSender.send`), and a board that goes DISARMED by no command the
host still means is a fault the host recovers from (:class:`hil.runtime.watch.BoardWatch`).
"""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hil.runtime.invariants import InjectedFault
from protocol.messages import BoardState
from tests.fault_support import check_honest_end, faulted_run_settings, run_faults

SETTINGS = faulted_run_settings(8)


# --------------------------------------------------------------------------- the Disarm retried late
def test_a_disarm_retried_after_the_operator_s_arm_is_seen_and_the_board_re_armed():
    """The stall at 3.551 s (0.3 s, the slew's start at 3.68 s inside it), the Disarm at 3.826 s into it,
    the Arm at 3.876 s: the board carried out the Arm, then the Disarm's retry (t = 3.98 s). Before, the
    run said ``completed`` with the board DISARMED from then to its end and no outage. Now the Arm
    supersedes the Disarm, which is never sent again: the board stays ARMED from the Arm to the end."""
    faults = [
        InjectedFault("stall", 3.551, {"duration_s": 0.3}),
        InjectedFault("disarm", 3.826),
        InjectedFault("arm", 3.876, {"after_disarm_s": 0.05}),
    ]
    sc, recorder = run_faults(faults)
    check_honest_end(faults, sc, recorder)
    s = recorder.summary
    assert s["exit"] == "completed" and s["link"]["superseded"] == 1
    assert recorder.first_event("unasked_disarm") is None
    rows = recorder.rows()
    after_arm = [state for t, state in zip(rows["t"], rows["board_state"], strict=True) if t > 4.0]
    assert set(after_arm) == {BoardState.ARMED}


def test_a_board_disarmed_by_no_command_the_host_means_is_a_fault_it_recovers_from(tmp_path):
    """The backstop: whatever makes a board the host holds armed go DISARMED (no operator's Disarm, no
    re-arm under way) is reported — ``unasked_disarm``, a ``disarmed`` fault — and re-armed."""
    from hil.link.board import BoardClient, StateEvent
    from hil.runtime.faults import FaultJournal
    from hil.runtime.runlog import EventLog, read_events
    from hil.runtime.watch import BoardWatch
    from hil.timing.clock import LockstepClock

    clock = LockstepClock()
    with BoardClient("emu://?units=4", clock=clock) as client:
        client.arm()
        events, journal = EventLog(tmp_path / "events.jsonl"), FaultJournal()
        watch = BoardWatch(client, events, journal, 0.25)
        watch.on_events([StateEvent(clock.now(), BoardState.ARMED, BoardState.DISARMED)])
        assert watch.take_upsets() == ["disarmed"] and watch.rearm_pending
        assert [f["kind"] for f in journal.faults] == ["disarmed"] and watch.unasked_disarms == 1
        watch.operator_disarm(clock.now())  # the operator's own Disarm is no fault
        watch.on_events([StateEvent(clock.now(), BoardState.ARMED, BoardState.DISARMED)])
        assert watch.take_upsets() == [] and watch.unasked_disarms == 1
        events.close()
    assert [r["kind"] for r in read_events(tmp_path / "events.jsonl")[0]][:2] == [
        "board_state",
        "unasked_disarm",
    ]


@SETTINGS
@given(
    stall_at=st.floats(0.5, 8.5),
    stall_s=st.sampled_from([0.27, 0.3, 0.45, 0.6]),
    disarm_before_end=st.floats(0.005, 0.1),
    arm_after_end=st.floats(0.005, 0.06),
)
def test_the_operator_s_disarm_in_a_stall_and_arm_after_it_at_any_phase_end_honestly(
    stall_at, stall_s, disarm_before_end, arm_after_end
):
    """A stall at a drawn moment of any phase, the operator's Disarm in its last moments (unanswered, so
    retried) and the Arm just after the link carries again (carried out before the Disarm's retry): a run
    that says ``completed`` ends with the board ARMED and live, and every invariant holds."""
    end = stall_at + stall_s
    disarm_at = round(end - disarm_before_end, 3)
    arm_at = round(end + arm_after_end, 3)
    faults = [
        InjectedFault("stall", round(stall_at, 3), {"duration_s": stall_s}),
        InjectedFault("disarm", disarm_at),
        InjectedFault("arm", arm_at, {"after_disarm_s": round(arm_at - disarm_at, 3)}),
    ]
    sc, recorder = run_faults(faults)
    check_honest_end(faults, sc, recorder)


# --------------------------------------------------------------------------- single faults, any moment
PHASE_CHANGES = (0.121, 2.121, 3.681, 9.661)  # still window, spin-up, slew's start, the last tick


@SETTINGS
@given(
    kind=st.sampled_from(["hang", "brownout", "unplug", "stall"]),
    at=st.one_of(st.floats(0.0, 10.0), st.sampled_from(PHASE_CHANGES)),
    duration_s=st.sampled_from([0.3, 0.8, 1.5]),
)
def test_a_board_fault_at_any_moment_ends_the_run_honestly(kind, at, duration_s):
    """A board fault at a drawn moment of the run (the phase changes among them): every invariant holds,
    a ``completed`` run ends with the board in hand, and the counts agree with the record."""
    params = {"duration_s": duration_s} if kind in ("unplug", "stall") else {}
    faults = [InjectedFault(kind, round(at, 3), params)]
    sc, recorder = run_faults(faults)
    check_honest_end(faults, sc, recorder)


@SETTINGS
@given(
    kind=st.sampled_from(["hang", "brownout", "unplug", "stall"]),
    before_end_s=st.one_of(st.floats(0.0, 0.4), st.sampled_from([0.0, 0.02, 0.25])),
    duration_s=st.sampled_from([0.3, 1.5]),
)
def test_a_board_fault_in_the_runs_last_moments_is_counted_and_said(kind, before_end_s, duration_s):
    """A board fault in the run's last 0.4 s, which the loop may end before it sees: the way out's Disarm
    finds the board reset under it. Before, the reset was counted nowhere and the run said "incomplete:
    the board is not confirmed disarmed" of a board that was booting; and an outage open at the end was
    measured after the way out's wait (the exit said 0.2 s, the summary 0.7 s). Now the reset is in the
    record (``after_the_run``), counted, and the run is lost, not completed; every open episode is measured
    at the run's end (:func:`tests.fault_support.check_honest_end`)."""
    at = round(PHASE_CHANGES[-1] - before_end_s, 3)
    params = {"duration_s": duration_s} if kind in ("unplug", "stall") else {}
    faults = [InjectedFault(kind, at, params)]
    sc, recorder = run_faults(faults)
    check_honest_end(faults, sc, recorder)
    s = recorder.summary
    if kind in ("hang", "brownout"):  # the board did reset, in the loop or on the way out — or, hung
        assert s["exit"] != "completed", s["exit"]  # still when the way out gave up, is not confirmed
        if s["board_resets"] == 0:  # disarmed
            assert s["exit"].startswith("incomplete: the run completed, but the board is not confirmed")
            assert s["final_disarm"]["ok"] is False and s["final_disarm"]["state"] == "ARMED"
        else:
            assert not s["exit"].startswith("incomplete"), s["exit"]


@pytest.mark.parametrize("spacing_s", [1.5, 2.5])
def test_repeated_unplugs_each_counted_and_recovered(spacing_s):
    """Three restarts of the board in a row, each after the host re-armed it: three resets reported (each
    POWER_ON), three re-arms, and the run completes with the board in hand."""
    faults = [InjectedFault("unplug", 4.2 + i * spacing_s, {"duration_s": 0.3}) for i in range(3)]
    sc, recorder = run_faults(faults)
    check_honest_end(faults, sc, recorder)
    s = recorder.summary
    assert s["exit"] == "completed"
    assert s["board_resets"] == 3 and s["rearms"] == 3
    assert [f["cause"] for f in s["faults"] if f["kind"] == "reset"] == ["POWER_ON"] * 3
