"""A slew the operator sends just after a board stall began never reached the board: its record says so.

The board's link stalls at ``at``; the host finds it only at its stale bound (0.25 s), so a slew sent in
between was taken as the host still steered — recorded ``applied`` with its ``slew_s``, a plan that never
ran: the board heard no setpoint of it, failed safe, and at the recovery's end the host re-planned the
slew to that target (``resume``, only in ``events.jsonl``). Now such a command is ``deferred`` when the
host stops steering without having heard the board after it, and ``applied`` again when the re-planned
slew starts (``slew_start_s``, the ``resume``'s time). A slew the board was heard steering to stays
``applied`` once, as before.

In lockstep against the emulated board, its stall at drawn moments across the slew and the hold.
"""

from __future__ import annotations

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.runtime import RunOptions, run
from hil.runtime.operator import OperatorCommand, ScheduledOperator
from hil.runtime.runlog import read_events
from hil.scenario import load_scenario

STALL_S = 0.8


def _run(tmp_path, at: float, sent: float):
    sc = load_scenario("cubesat-1u").with_changes(fault_options={"stall": [f"{at:.3f}:{STALL_S}"]})
    operator = ScheduledOperator(
        [(sent, OperatorCommand(1, "slew", target=(10.0, -5.0, 20.0), origin="test"))]
    )
    result = run(sc, RunOptions(out_root=tmp_path, duration_s=at + 4.0, observer=operator))
    events, bad = read_events(result.run_dir / "events.jsonl")
    assert bad == 0
    return result.summary, events


@settings(max_examples=5, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
@given(at=st.floats(14.0, 34.0), after=st.floats(0.03, 0.2))
def test_a_slew_sent_after_a_stall_began_is_deferred_to_the_recoverys_resume(tmp_path_factory, at, after):
    """The stall begins at ``at``; the slew goes ``after`` later, before the stale bound: its record ends
    ``applied`` at the ``resume`` that re-planned it, ``deferred`` in between — never ``applied`` alone at
    the moment it was sent."""
    s, events = _run(tmp_path_factory.mktemp("run"), at, at + after)
    steps = [e for e in events if e["kind"] == "command" and e["id"] == 1]
    resume = next(e for e in events if e["kind"] == "resume" and e["t"] > at)
    assert [e["status"] for e in steps] == ["applied", "deferred", "applied"], steps
    assert steps[1]["t"] <= resume["t"] and "not heard" in steps[1]["reason"]
    assert steps[2]["slew_start_s"] == resume["t"] and steps[2]["slew_s"] == resume["slew_s"], (steps, resume)
    entry = s["operator"][0]
    assert entry["status"] == "applied" and entry["status_t"] == steps[2]["t"]
    assert s["exit"] == "completed", s["exit"]


@settings(max_examples=3, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
@given(at=st.floats(14.0, 34.0), before=st.floats(0.1, 2.0))
def test_a_slew_the_board_was_heard_steering_to_stays_applied(tmp_path_factory, at, before):
    """The slew goes ``before`` the stall begins: the board was heard steering to it, its record is
    ``applied`` once (the recovery's re-plan is the host's, as for any slew interrupted by a fault)."""
    s, events = _run(tmp_path_factory.mktemp("run"), at, at - before)
    steps = [e for e in events if e["kind"] == "command" and e["id"] == 1]
    assert [e["status"] for e in steps] == ["applied"], steps
    assert s["operator"][0]["status"] == "applied"
