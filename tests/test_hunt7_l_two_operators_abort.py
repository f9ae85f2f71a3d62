"""Two operators at once, one aborting (area L, hunt 7): the ground station and a script, or a campaign's
operator and a script, each carry out commands through their own :class:`~hil.runtime.operator.Operator`.
Each knew only its own abort: a script's Arm in the tick of a campaign's abort went out, superseded the
abort's Disarm and re-armed the board, and the run ended "aborted: … the Disarm failed; the board's link
watchdog fails it safe" — on a link that carried everything. Now every command after an abort's Disarm is
out is refused, whichever operator sends it, and the abort ends the run on the board's word.
"""

from __future__ import annotations

from fault_support import faulted_run_settings, short_scenario
from hypothesis import example, given
from hypothesis import strategies as st

from hil.runtime import RunOptions, run
from hil.runtime.observer import Observers
from hil.runtime.operator import COMMANDS, OperatorCommand, ScheduledOperator
from hil.runtime.record import RunRecorder


@faulted_run_settings(max_examples=4)
@given(
    other=st.sampled_from(COMMANDS), abort_at=st.floats(1.0, 8.0), after=st.sampled_from([0.0, 0.001, 0.015])
)
@example(other="arm", abort_at=5.0, after=0.0)
def test_a_command_from_another_operator_during_an_abort_is_refused(other, abort_at, after):
    abort_at = round(abort_at, 3)
    sc = short_scenario()
    recorder = RunRecorder(sc.n_units)
    target = (10.0, 0.0, 0.0) if other == "slew" else None
    campaign = ScheduledOperator([(abort_at, OperatorCommand(1, "abort", None, "campaign"))])
    script = ScheduledOperator([(round(abort_at + after, 3), OperatorCommand(1, other, target, "test"))])
    result = run(sc, RunOptions(out_root=None, observer=Observers(recorder, campaign, script)))
    s = result.summary
    by_origin = {o["origin"]: o for o in s["operator"]}
    assert by_origin["campaign"]["status"] == "acked", by_origin
    assert by_origin["test"]["status"] == "refused", by_origin
    assert "being aborted (command 1 from the fault campaign)" in by_origin["test"]["reason"]
    assert s["exit"].startswith("aborted: from the fault campaign (command 1: board disarmed"), s["exit"]
    assert not [
        e
        for e in recorder.events
        if e["kind"] == "command" and e["origin"] == "test" and e["status"] != "refused"
    ]
