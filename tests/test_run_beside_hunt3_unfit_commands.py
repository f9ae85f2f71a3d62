"""Operator commands that cannot be carried out as given, from a sender other than the ground station (whose
parser refuses them): a fault campaign's or a script's :class:`~hil.runtime.operator.ScheduledOperator`,
an observer plugin. A slew to NaN° (or ±inf°) went on to the controller and its NaN setpoint ended the
run with ``error: ActuatorSetpoint.units[0].gimbal = nan is out of range`` (status 2); a slew without a
target, or a command of an unknown name, ended it with a bare ``AssertionError``; a slew to 1e160° was
"applied". Each is now refused — its reason in the operator's log and ``events.jsonl`` — and the run goes
on as if it had not come.

Lockstep runs of the short scenario (tests/fault_support.py), the command at a drawn moment in any phase.
"""

from __future__ import annotations

import functools
import math

from fault_support import faulted_run_settings, short_scenario
from hypothesis import example, given
from hypothesis import strategies as st

from hil.runtime import RunOptions, run
from hil.runtime.observer import Observers
from hil.runtime.operator import OperatorCommand, ScheduledOperator
from hil.runtime.record import RunRecorder

BAD_ANGLES = st.sampled_from([math.nan, math.inf, -math.inf, 1e160, -181.0, 360.0])
UNFIT = st.one_of(
    st.tuples(BAD_ANGLES, st.just(0.0), st.just(0.0)).map(lambda a: OperatorCommand(1, "slew", a, "test")),
    st.tuples(st.just(10.0), BAD_ANGLES, st.just(0.0)).map(lambda a: OperatorCommand(1, "slew", a, "test")),
    st.tuples(st.just(0.0), st.just(5.0), BAD_ANGLES).map(lambda a: OperatorCommand(1, "slew", a, "test")),
    st.just(OperatorCommand(1, "slew", None, "test")),
    st.sampled_from(["reboot", "", "ARM", "slew "]).map(lambda n: OperatorCommand(1, n, None, "test")),
)


@faulted_run_settings(max_examples=6)
@given(command=UNFIT, moment=st.floats(0.5, 9.6))
@example(command=OperatorCommand(1, "slew", (math.nan, 0.0, 0.0), "test"), moment=6.0)  # the hold: exit 2
@example(command=OperatorCommand(1, "slew", None, "test"), moment=4.0)  # the slew: AssertionError
@example(command=OperatorCommand(1, "reboot", None, "test"), moment=2.5)  # the spin-up: AssertionError
def test_an_unfit_command_is_refused_and_the_run_goes_on(command, moment):
    sc = short_scenario()
    recorder = RunRecorder(sc.n_units)
    observer = Observers(recorder, ScheduledOperator([(round(moment, 3), command)]))
    result = run(sc, RunOptions(out_root=None, observer=observer, rows_to_observer=True))
    s = result.summary
    assert s["exit"] == "completed", s["exit"]
    [entry] = s["operator"]
    assert entry["status"] == "refused" and entry["command"] == command.name, entry
    assert "slew" in entry["reason"] or "not a command" in entry["reason"], entry["reason"]
    said = [e for e in recorder.events if e["kind"] == "command"]
    assert [e["status"] for e in said] == ["refused"] and said[0]["reason"] == entry["reason"]
    # lockstep is deterministic: the run ends where the run without the command ends
    assert s["final_error_deg"] == _without_commands()["final_error_deg"]


@functools.cache
def _without_commands() -> dict:
    sc = short_scenario()
    return run(sc, RunOptions(out_root=None, observer=RunRecorder(sc.n_units), rows_to_observer=True)).summary
