"""A board whose power manager sheds the rotors (a sagging pack: SHED) in a lockstep run of the real host:
the run's record says so (``power_shed``, hil/runtime/actuators.py)."""

from __future__ import annotations

from hil.runtime import RunOptions, run
from hil.runtime.record import RunRecorder
from tests.fault_support import short_scenario


def test_a_board_that_sheds_its_rotors_says_so_in_the_record():
    """The pack sags until the board's power manager sheds the rotors (SHED): the run's record says so — a
    ``power_shed`` note with the state, once an episode — where only the rotors' not following was said,
    never why (a hunt's finding)."""
    sc = short_scenario()
    sc = sc.with_changes(fault_options={**sc.fault_options, "sag": ["4@5/2"]})
    recorder = RunRecorder(sc.n_units)
    run(sc, RunOptions(out_root=None, observer=recorder, rows_to_observer=True))
    shed = [e for e in recorder.events if e["kind"] == "power_shed"]
    assert shed and shed[0]["state"] in ("SHED", "BROWN_OUT"), [e["kind"] for e in recorder.events][-20:]
    assert len(shed) == 1  # once an episode, not once a tick
    assert [f for f in recorder.summary["faults"] if f["kind"] == "power_shed"]
