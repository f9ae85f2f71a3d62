"""A run whose final Disarm failed — the board frozen or its link stalled over the run's end — once said
``completed`` (status 0): only ``events.jsonl`` had ``disarm_failed``; ``summary.json`` and the printed
summary said nothing, though the board may still be spinning its rotors. Now ``summary.json``'s
``final_disarm`` says how the way out's Disarm went, a run that completed but whose board is not
confirmed disarmed says ``incomplete: …`` (status 1), and the printed summary says it plainly.

In lockstep: a link stall (the board's ``stall`` fault: nothing carried either way) drawn from before the
run's end to after it, its length either side of the way out's wait (1 s).
"""

from __future__ import annotations

import functools

from fault_support import faulted_run_settings, run_faults
from hypothesis import example, given
from hypothesis import strategies as st

from hil.cli.run import EXIT_COMPLETED, exit_status, format_summary
from hil.montecarlo.runner import fault_bounds
from hil.runtime.invariants import InjectedFault, check_run


@functools.cache
def run_end() -> float:
    """Host time the short scenario's run is up, unfaulted (its slew's start + its duration)."""
    sc, recorder = run_faults([])
    slew = next(e["t"] for e in recorder.events if e["kind"] == "slew_start")
    return slew + sc.slew.duration_s


@faulted_run_settings(20)
@given(before_end=st.floats(-0.3, 0.6), stall_s=st.floats(0.3, 3.0))
@example(before_end=0.1, stall_s=3.0)  # the reviewer's fw_end: frozen 0.2 s before the end, for 3 s
@example(before_end=0.05, stall_s=1.5)
@example(before_end=0.0, stall_s=0.5)  # over the Disarm, not for all of its wait: answered late
@example(before_end=-0.02, stall_s=2.0)  # just after the last tick, under the Disarm itself
def test_a_failed_final_disarm_is_said_and_the_run_not_completed(before_end, stall_s):
    fault = InjectedFault("stall", run_end() - before_end, {"duration_s": stall_s})
    sc, recorder = run_faults([fault])
    s = recorder.summary
    events = recorder.events
    final = s["final_disarm"]
    way_out = [e for e in events if e["kind"] in ("disarmed", "disarm_failed")]
    if any(e["kind"] == "disarm_failed" for e in way_out):
        assert final["sent"] and final["ok"] is False and final["error"]
        assert s["exit"] != "completed" and exit_status(s) != EXIT_COMPLETED, s["exit"]
        text = format_summary(s)
        assert "not confirmed disarmed" in text, text
        if not s.get("lost"):
            assert s["exit"].startswith("incomplete: the run completed, but the board is not confirmed")
    elif way_out:
        assert final["sent"] and final["ok"] is True
        assert "not confirmed disarmed" not in format_summary(s)
    else:
        assert not final["sent"]
    report = check_run([fault], recorder, fault_bounds(sc))
    assert report.violations["honest_exit"] == [], report.violations["honest_exit"]


def test_the_reviewer_s_case_fails_its_disarm():
    """The stall drawn above at its sharpest: the board frozen 0.1 s before the end for 3 s."""
    fault = InjectedFault("stall", run_end() - 0.1, {"duration_s": 3.0})
    _, recorder = run_faults([fault])
    s = recorder.summary
    assert [e["kind"] for e in recorder.events if e["kind"].startswith("disarm")] == ["disarm_failed"]
    assert s["exit"].startswith("incomplete: the run completed, but the board is not confirmed disarmed")
    assert exit_status(s) == 1
    assert s["final_disarm"]["ok"] is False
