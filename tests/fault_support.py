"""A short lockstep run of the default scenario with injected faults, and the checks every such run must
pass (tests/test_fault_timings_more.py, tests/test_fault_overlaps.py)."""

from __future__ import annotations

from hypothesis import HealthCheck, Phase, settings

from hil.montecarlo.fault_plan import fault_options, operator_schedule
from hil.montecarlo.runner import fault_bounds
from hil.runtime import RunOptions, run
from hil.runtime.faults import BoardLink
from hil.runtime.invariants import InjectedFault, InvariantReport, check_run
from hil.runtime.observer import Observers
from hil.runtime.operator import ScheduledOperator
from hil.runtime.record import RunRecorder
from hil.scenario import Scenario, load_scenario
from protocol.messages import BoardState

SCENARIO = "cubesat-1u"
DURATION_S = 6.0  # after the slew's start (~3.7 s): a run of ~10 s simulated, ~0.4 s of wall time


def faulted_run_settings(max_examples: int) -> settings:
    """Hypothesis settings for drawn faulted runs: derandomized (the same draws in every CI run) and not
    shrunk (each run costs ~0.4 s: a failing one stays bounded too)."""
    return settings(
        max_examples=max_examples,
        deadline=None,
        derandomize=True,
        phases=[Phase.explicit, Phase.generate],
        suppress_health_check=[HealthCheck.too_slow],
    )


def short_scenario() -> Scenario:
    """The default scenario, :data:`DURATION_S` after its slew starts."""
    sc = load_scenario(SCENARIO)
    return sc.with_changes(slew=sc.slew.__class__(**{**sc.slew.__dict__, "duration_s": DURATION_S}))


def run_faults(faults: list[InjectedFault]) -> tuple[Scenario, RunRecorder]:
    """The short scenario run with ``faults`` (the board's through its options, the operator's scheduled),
    recorded in memory."""
    sc = short_scenario()
    recorder = RunRecorder(sc.n_units)
    schedule = operator_schedule(tuple(faults))
    observer = Observers(recorder, ScheduledOperator(list(schedule))) if schedule else recorder
    sc = sc.with_changes(fault_options=fault_options(tuple(faults), sc.fault_options))
    run(sc, RunOptions(out_root=None, observer=observer, rows_to_observer=True))
    return sc, recorder


def check_honest_end(faults: list[InjectedFault], sc: Scenario, recorder: RunRecorder) -> InvariantReport:
    """Every invariant of the campaigns, and: ``completed`` only with the board live and ARMED at the end;
    the summary's reset and failsafe counts are those of the journal and of ``events.jsonl``."""
    report = check_run(faults, recorder, fault_bounds(sc))
    assert report.ok, (report.violations, [f.describe() for f in faults])
    s = recorder.summary
    rows = recorder.rows()
    if s["exit"] == "completed":
        assert rows["board_link"][-1] == BoardLink.LIVE, "completed without a live board at the end"
        assert rows["board_state"][-1] == BoardState.ARMED, (
            f"completed with the board {BoardState(int(rows['board_state'][-1])).name} at the end"
        )
    end = float(rows["t"][-1])  # the run's last tick: where its loop ended
    for episode in [*s["outages"], *s["phone_gap_list"]]:  # measured at the run's end, as its exit is
        if episode["end"] is None:
            assert abs(episode["duration_s"] - (end - episode["start"])) < 1e-6, (episode, end)
    final = s.get("final_disarm") or {}
    if final.get("state") in ("BOOT", "DISARMED"):  # the board's word: it drives nothing
        assert final["ok"] is not False, final
    journal = s["faults"]
    assert s["board_resets"] == sum(f["kind"] == "reset" for f in journal)
    assert s["board_resets"] == sum(e["kind"] == "board_reset" for e in recorder.events)
    assert s["failsafe_events"] == sum(f["kind"] == "failsafe" for f in journal)
    return report
