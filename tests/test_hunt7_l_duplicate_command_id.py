"""Two operators at once, reusing a command id (area L, hunt 7): a script's or two scripts' commands of
one origin carry their own ids, and the operator log keys a command's steps by origin and id. Before, a
second command 1 overwrote the first one's entry: a Disarm's entry said ``acked`` for the Arm that
followed it (the Arm in no entry of the summary), and its ``events.jsonl`` steps were taken for the
first command's by the ground station's page. Now the second is refused as a duplicate, in a record and
an entry of its own, and is not carried out.
"""

from __future__ import annotations

import pytest
from fault_support import faulted_run_settings, short_scenario
from hypothesis import given
from hypothesis import strategies as st

from hil.runtime import RunOptions, run
from hil.runtime.observer import Observers
from hil.runtime.operator import COMMANDS, OperatorCommand, ScheduledOperator, unfit
from hil.runtime.record import RunRecorder


@faulted_run_settings(max_examples=4)
@given(second=st.sampled_from(COMMANDS), first_at=st.floats(4.0, 5.5), after=st.floats(0.0, 1.0))
def test_a_second_command_of_the_same_origin_and_id_is_refused_and_leaves_the_first_alone(
    second, first_at, after
):
    first_at, at = round(first_at, 3), round(first_at + after, 3)
    sc = short_scenario()
    recorder = RunRecorder(sc.n_units)
    target = (10.0, 0.0, 0.0) if second == "slew" else None
    one = ScheduledOperator([(first_at, OperatorCommand(1, "hold", None, "test"))])
    two = ScheduledOperator([(at, OperatorCommand(1, second, target, "test"))])
    result = run(sc, RunOptions(out_root=None, observer=Observers(recorder, one, two)))
    s = result.summary
    assert [(o["command"], o["status"]) for o in s["operator"]] == [("hold", "applied"), (second, "refused")]
    assert "duplicate id" in s["operator"][1]["reason"]
    commands = [e for e in recorder.events if e["kind"] == "command"]
    assert [(e["id"], e["command"], e["status"]) for e in commands] == [
        (1, "hold", "applied"),
        (None, second, "refused"),
    ]
    assert commands[1]["duplicate_id"] == 1
    assert s["exit"] == "completed", s["exit"]  # not carried out: no Disarm, no abort


@pytest.mark.parametrize("angle", [True, False, 10**400, float("nan"), "5"])
def test_a_slew_angle_that_is_no_finite_number_is_unfit(angle):
    """``True`` was taken as a 1° slew (a bool is an int to Python), and an integer past a float's range
    raised OverflowError out of ``math.isfinite``: both are no angle."""
    said = unfit(OperatorCommand(1, "slew", (0.0, angle, 0.0)))  # type: ignore[arg-type]
    assert said is not None and "pitch" in said
    assert unfit(OperatorCommand(2, "slew", (0.0, 5, 0.0))) is None
