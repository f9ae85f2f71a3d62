"""A board that fails safe just after the run's last control tick — its link stalled over the end, its
link watchdog firing after the loop stopped — once left no trace: the way out's final Disarm heard the
FAILSAFE and dropped it with the Disarm's own changes of state, so ``events.jsonl`` had no ``board_state``
FAILSAFE, ``summary.json`` counted no failsafe and the run said ``completed`` (status 0) for a board that
the host's commands had not reached since before the end. Now the failsafe is in the record
(``after_the_run``), counted, and the run is ``lost: board failed safe as the run ended …`` as a reset heard
on the way out makes it.

In lockstep: a link stall (the board's ``stall`` fault) drawn to start 0.1–0.4 s before the run's end
(its commands not reaching the board for that long at the end), for 0.3–1.5 s; the board's own log
(``state FAILSAFE -> …``) says whether it failed safe.
"""

from __future__ import annotations

import functools

from fault_support import check_honest_end, faulted_run_settings, run_faults
from hypothesis import example, given
from hypothesis import strategies as st

from hil.cli.run import EXIT_COMPLETED, exit_status
from hil.runtime.invariants import InjectedFault


@functools.cache
def run_end() -> float:
    """Host time the short scenario's run is up, unfaulted (its slew's start + its duration)."""
    sc, recorder = run_faults([])
    slew = next(e["t"] for e in recorder.events if e["kind"] == "slew_start")
    return slew + sc.slew.duration_s


def _board_failed_safe(events: list[dict]) -> bool:
    """The board's own word (its log, heard once the link carries again): it was in FAILSAFE."""
    return any(e["kind"] == "board_log" and "FAILSAFE" in str(e.get("text")) for e in events)


@faulted_run_settings(12)
@given(before_end=st.floats(0.1, 0.4), stall_s=st.floats(0.3, 1.5))
@example(before_end=0.2, stall_s=0.4)  # the watchdog fires ~0.05 s after the last tick
@example(before_end=0.1, stall_s=0.3)
def test_a_failsafe_heard_on_the_way_out_is_recorded_and_the_run_not_completed(before_end, stall_s):
    fault = InjectedFault("stall", run_end() - before_end, {"duration_s": stall_s})
    sc, recorder = run_faults([fault])
    s, events = recorder.summary, recorder.events
    if not _board_failed_safe(events):
        return  # the stall ended (or the Disarm went through) before the board's watchdog fired
    assert s["failsafe_events"] >= 1, s["exit"]
    assert any(e["kind"] == "board_state" and e.get("new") == "FAILSAFE" for e in events)
    failsafes = [f for f in s["faults"] if f["kind"] == "failsafe"]
    assert failsafes, s["faults"]
    if any(f.get("after_the_run") for f in failsafes):  # (one heard in the run is recovered from, or not)
        assert s["exit"] != "completed" and exit_status(s) != EXIT_COMPLETED, s["exit"]
        assert s["exit"].startswith("lost: "), s["exit"]  # an outage still open says it first
    check_honest_end([fault], sc, recorder)  # every campaign invariant, the counts agreeing


def test_the_sharpest_case_names_the_failsafe_in_its_exit():
    """Stalled 0.2 s before the end for 0.4 s: the board's watchdog fires after the last tick."""
    _, recorder = run_faults([InjectedFault("stall", run_end() - 0.2, {"duration_s": 0.4})])
    s = recorder.summary
    assert s["exit"].startswith("lost: board failed safe as the run ended (its link watchdog"), s["exit"]
    assert [f for f in s["faults"] if f["kind"] == "failsafe"][0]["after_the_run"] is True
