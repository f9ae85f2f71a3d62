"""A missed pointing requirement is explained only by what changed the run (:func:`hil.runtime.summary.
requirement`, judged by :func:`hil.runtime.invariants.check_run`'s ``back_in_control``): hostile phone
readings are dropped and counted and nothing else changes (docs/faults.md), so they explain no miss.

What broke: every journal record since the slew's start counted as a fault that explained a miss — the
drop notes of one spoofed reading too. A controller that did not settle, in a run given one spoof, said
``faults: readings_dropped x2`` and passed the judge; the same run without the spoof was failed.
"""

from __future__ import annotations

import pytest

from hil.montecarlo.fault_plan import fault_options
from hil.montecarlo.runner import fault_bounds
from hil.runtime import RunOptions, run
from hil.runtime.invariants import InjectedFault, check_run
from hil.runtime.record import RunRecorder
from hil.scenario import Scenario
from tests.fault_support import short_scenario


def _never_settles() -> Scenario:
    """The short scenario, long enough for its slew (24 s after its start), held to a pointing no
    controller reaches (1e-9°): a miss nothing but the controller explains."""
    sc = short_scenario()
    sc = sc.with_changes(slew=sc.slew.__class__(**{**sc.slew.__dict__, "duration_s": 24.0}))
    return sc.with_changes(settle_deg=1e-9)


@pytest.mark.parametrize("spoof", ["nan", "future", "burst"])
def test_dropped_hostile_readings_explain_no_missed_requirement(spoof):
    """A spoof mid-slew on a run whose controller cannot settle: its readings are dropped and noted, the
    requirement's miss stays unexplained, and the judge says so."""
    faults = [InjectedFault("phone_spoof", 12.0, {"spoof": spoof})]
    sc = _never_settles()
    recorder = RunRecorder(sc.n_units)
    sc = sc.with_changes(fault_options=fault_options(tuple(faults), sc.fault_options))
    run(sc, RunOptions(out_root=None, observer=recorder, rows_to_observer=True))
    s = recorder.summary
    assert any(f["kind"] == "readings_dropped" for f in s["faults"])  # the spoof was seen and counted
    assert s["requirement"]["met"] is False and s["requirement"]["explained"] is False, s["requirement"]
    assert "readings_dropped" not in s["requirement"]["why"]
    report = check_run(faults, recorder, fault_bounds(sc))
    assert report.violations["back_in_control"], report.violations
    assert not report.violations["faults_detected"]
