"""An operator's hold or slew while the host does not steer the board (area L, hunt 7).

Before, a slew or a hold while the operator had the run disarmed (suspended) was recorded ``applied`` at
once, its ``slew_s`` a plan that never ran — the host sent no setpoints, and the slew that did run was
planned at the Arm's warm-up end; one in the slew phase while the board was out of hand (a link stall:
no live telemetry) was ``applied`` too, its reference moving on with no setpoint going out. Now the first
is ``deferred`` (with why), then ``applied`` when its slew starts (``slew_start_s``) — or ``superseded`` by
a newer target — and the second is refused, saying why.

Lockstep runs of the short scenario (tests/fault_support.py), the commands at drawn moments, through
:class:`~hil.runtime.operator.ScheduledOperator` (the path a campaign's and a script's commands take).
"""

from __future__ import annotations

from fault_support import faulted_run_settings, short_scenario
from hypothesis import example, given
from hypothesis import strategies as st

from hil.runtime import RunOptions, run
from hil.runtime.observer import Observers
from hil.runtime.operator import OperatorCommand, ScheduledOperator
from hil.runtime.record import RunRecorder

RETARGETS = st.one_of(
    st.just(OperatorCommand(2, "hold", None, "test")),
    st.tuples(st.floats(-60, 60), st.floats(-30, 30), st.floats(-90, 90)).map(
        lambda a: OperatorCommand(2, "slew", a, "test")
    ),
)


def _steps(recorder: RunRecorder, ident: int) -> list[dict]:
    return [e for e in recorder.events if e["kind"] == "command" and e["id"] == ident]


@faulted_run_settings(max_examples=4)
@given(command=RETARGETS, disarm_at=st.floats(4.0, 6.0), after=st.floats(0.05, 2.0))
@example(command=OperatorCommand(2, "slew", (30.0, 0.0, 0.0), "test"), disarm_at=5.0, after=1.0)
def test_a_retarget_while_disarmed_is_deferred_until_its_slew_starts(command, disarm_at, after):
    disarm_at, at = round(disarm_at, 3), round(disarm_at + after, 3)
    arm_at = round(disarm_at + 2.5, 3)
    sc = short_scenario()
    recorder = RunRecorder(sc.n_units)
    schedule = [
        (disarm_at, OperatorCommand(1, "disarm", None, "test")),
        (at, command),
        (arm_at, OperatorCommand(3, "arm", None, "test")),
    ]
    result = run(sc, RunOptions(out_root=None, observer=Observers(recorder, ScheduledOperator(schedule))))
    steps = _steps(recorder, 2)
    assert [e["status"] for e in steps] == ["deferred", "applied"], steps
    deferred, applied = steps
    assert "suspended" in deferred["reason"] and "Arm" in deferred["reason"]
    resume = next(e for e in recorder.events if e["kind"] == "resume" and e["t"] > arm_at)
    # applied when its slew starts — after the Arm, the plan that runs (not the one made while disarmed)
    assert applied["t"] > arm_at and applied["slew_start_s"] == resume["t"]
    assert applied["slew_s"] == resume["slew_s"]
    s = result.summary
    assert [(o["command"], o["status"]) for o in s["operator"]] == [
        ("disarm", "acked"),
        (command.name, "applied"),
        ("arm", "acked"),
    ]
    assert s["exit"] == "completed", s["exit"]


def test_a_newer_target_while_disarmed_supersedes_the_deferred_one():
    sc = short_scenario()
    recorder = RunRecorder(sc.n_units)
    schedule = [
        (5.0, OperatorCommand(1, "disarm", None, "test")),
        (6.0, OperatorCommand(2, "slew", (30.0, 0.0, 0.0), "test")),
        (6.5, OperatorCommand(3, "hold", None, "test")),
        (8.0, OperatorCommand(4, "arm", None, "test")),
    ]
    run(sc, RunOptions(out_root=None, observer=Observers(recorder, ScheduledOperator(schedule))))
    assert [e["status"] for e in _steps(recorder, 2)] == ["deferred", "superseded"]
    assert [e["status"] for e in _steps(recorder, 3)] == ["deferred", "applied"]


@faulted_run_settings(max_examples=3)
@given(command=RETARGETS, at=st.floats(5.26, 5.48))
@example(command=OperatorCommand(2, "slew", (30.0, 0.0, 0.0), "test"), at=5.45)
def test_a_retarget_with_the_board_out_of_hand_is_never_applied_meanwhile(command, at):
    """A link stall from 5.0 s for 0.5 s (telemetry stale from ~5.23 s, the board fails safe at ~5.5 s):
    the slew or hold in the outage, in the slew phase, is refused — before, ``applied``, its reference
    running on while no setpoint went out."""
    sc = short_scenario().with_changes(fault_options={"stall": ["5.0:0.5"]})
    recorder = RunRecorder(sc.n_units)
    schedule = [(round(at, 3), command)]
    result = run(sc, RunOptions(out_root=None, observer=Observers(recorder, ScheduledOperator(schedule))))
    steps = _steps(recorder, 2)
    assert [e["status"] for e in steps] == ["refused"], steps
    assert "in hand" in steps[0]["reason"]
    assert result.summary["exit"] == "completed"
