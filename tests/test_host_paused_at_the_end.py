"""A host paused across its run's end (SIGSTOP, a swapped-out process) once left the board armed with no
one commanding it: after the pause it read the FAILSAFE the pause caused, ran one more control tick
though the run's time was up, that tick sent a re-arm, and the run let go of the board — no Disarm, since
the way out disarmed only a board that said ARMED. The Arm then armed it and its link watchdog tripped
again (5 runs out of 5 of a wall-clock reviewer's). Now no re-arm is started once the run's time is up,
and the way out sends a Disarm to any board not known DISARMED or with an Arm of the host's in flight.

Reproduced in lockstep (tests/host_pause_support.py): the pause's start drawn over the last seconds
before the end, its length from shorter than the board's link timeout to seconds past the end — the
pause ending before the end (re-armed, the Arm maybe still in flight at the end) and after it.
"""

from __future__ import annotations

from fault_support import DURATION_S, faulted_run_settings
from host_pause_support import PausedRun, paused_run
from hypothesis import example, given
from hypothesis import strategies as st

from hil.montecarlo.runner import fault_bounds
from hil.runtime.invariants import check_run
from protocol.messages import BoardState


def check_invariants(run: PausedRun) -> None:
    """The campaigns' invariants on the run's record; a host paused past the end cannot end on time (it
    ends when it runs again), so that one is not held against it."""
    report = check_run([], run.recorder, fault_bounds(run.scenario))
    paused_at = run.pause.paused_at
    assert paused_at is not None
    crossed = paused_at + run.pause.pause_s > run.end
    violations = {
        name: [v for v in found if not (crossed and v.startswith("the run was due to end"))]
        for name, found in report.violations.items()
    }
    assert not any(violations.values()), violations


@faulted_run_settings(24)
@given(before_end=st.floats(0.02, 2.5), pause_s=st.floats(0.05, 4.0))
@example(before_end=0.5, pause_s=3.0)  # the reviewer's: paused 7.5 s into an 8 s run for 3 s
@example(before_end=0.4, pause_s=2.0)
@example(before_end=0.3, pause_s=0.6)  # back after the end, the board failed safe meanwhile
@example(before_end=0.9, pause_s=0.6)  # back before the end: re-armed, the Arm in flight near the end
@example(before_end=0.02, pause_s=5.0)  # the very last tick
def test_a_host_paused_across_the_end_leaves_the_board_disarmed(before_end, pause_s):
    run = paused_run(DURATION_S - before_end, pause_s)
    end = run.end
    late_arms = [e for e in run.events if e["kind"] == "rearm_sent" and e["t"] >= end - 1e-9]
    assert not late_arms, f"a re-arm started once the run's time was up: {late_arms}"
    # the board's own word, shortly after the host let go (well within its link watchdog): not ARMED
    assert run.board_state_after(0.1) is not BoardState.ARMED, (run.summary["exit"], run.events[-8:])
    way_out = [e for e in run.events if e["kind"] in ("disarmed", "disarm_failed")]
    armed = [e["t"] for e in run.events if e["kind"] in ("armed", "rearm_sent")]
    if armed and armed[-1] > run.pause.paused_at:  # an Arm since the pause: a Disarm after it, on the way out
        assert way_out and way_out[-1]["reason"] == "run ended" and way_out[-1]["t"] >= armed[-1]
    check_invariants(run)
