"""A host that itself stops (its process paused or swapped out) finds the board's backlog when it runs
again: the board failed safe seconds before. The run once said ``completed`` with an outage of ~0.03 s
for a host paused 12 s with ``--recover-within 5``, and a pause of 0.4–2 s left no fault at all: the
FAILSAFE read from the backlog was dated by its read, and the host's own stall was journalled nowhere.
Now the session dates a state change by when the board made it (:mod:`hil.link.board.made_at`), and a
control tick more than ``stale_after_s`` after its deadline is a ``host_stall`` fault from that deadline:
an outage the bound applies to.

In lockstep (tests/host_pause_support.py: the clock jumps at a control tick, the board runs on), the
moment drawn over the slew and the hold, the pause either side of the board's link timeout and of the
run's bound; and through the sans-IO session with injected time.
"""

from __future__ import annotations

from fault_support import DURATION_S, faulted_run_settings
from host_pause_support import paused_run
from hypothesis import example, given, settings
from hypothesis import strategies as st
from test_board_link_beside_echo import connected, telemetry

from hil.cli.run import EXIT_COMPLETED, EXIT_LOST, exit_status
from hil.link.board import StateEvent
from hil.montecarlo.runner import fault_bounds
from hil.runtime.faults import STALE_AFTER_S
from hil.runtime.invariants import check_run
from protocol.frame import Framer
from protocol.messages import BoardState

TICK_S = 0.02  # the default scenario's control period
TELEMETRY_S = 0.05  # its board's telemetry period (20 Hz)
RECOVER_S = 3.0  # the bound these runs are held to


@faulted_run_settings(20)
@given(at=st.floats(0.1, DURATION_S - 0.3), pause_s=st.floats(0.05, 6.0))
@example(at=1.0, pause_s=4.0)  # the reviewer's: longer than --recover-within, "completed" with 0.03 s
@example(at=2.0, pause_s=1.0)  # shorter: no fault at all before
@example(at=0.5, pause_s=0.4)
@example(at=3.0, pause_s=0.2)  # within the board's link timeout: no stall, nothing to say
def test_a_paused_host_journals_its_stall_and_the_board_s_failsafe_when_it_happened(at, pause_s):
    run = paused_run(at, pause_s, recover_within_s=RECOVER_S)
    paused_at = run.pause.paused_at
    assert paused_at is not None
    s = run.summary
    faults = s["faults"]
    stalls = [f for f in faults if f["kind"] == "host_stall"]
    if pause_s <= STALE_AFTER_S:
        assert not stalls and s["host_stalls"] == 0
        return
    # the stall, from the deadline the host missed, an outage from there
    assert len(stalls) == 1 and s["host_stalls"] == 1
    assert abs(stalls[0]["t"] - paused_at) < 1e-6 and abs(stalls[0]["late_ms"] - pause_s * 1e3) < 1e-3
    outage = next(o for o in s["outages"] if abs(o["start"] - paused_at) < 1e-6)
    assert "host_stall" in outage["causes"]
    assert outage["duration_s"] >= min(pause_s, run.end - paused_at) - 1e-9, outage
    # the board failed safe by its link timeout during the pause: dated then, not when it was read
    for f in (f for f in faults if f["kind"] == "failsafe" and f["t"] >= paused_at):
        assert f["t"] <= paused_at + STALE_AFTER_S + TELEMETRY_S + 2 * TICK_S, (f, paused_at)
        break
    # a pause past the bound (before the run's end) is a lost board, said so; within it, back in hand
    back_at = paused_at + pause_s
    if pause_s > RECOVER_S and back_at < run.end:
        assert s["exit"].startswith("lost:") and "host_stall" in s["exit"], s["exit"]
        assert exit_status(s) == EXIT_LOST
        assert abs(float(s["exit"].split(" for ")[1].split(" s")[0]) - pause_s) <= 0.05
    elif back_at < run.end - 1.5:  # back with time to recover: completed, the outage over
        assert s["exit"] == "completed" and exit_status(s) == EXIT_COMPLETED, s["exit"]
        assert outage["recovered"]
    report = check_run([], run.recorder, fault_bounds(run.scenario))
    crossed = back_at > run.end  # it cannot end on time: it ends when it runs again
    beyond = pause_s > RECOVER_S  # lost, for a fault no campaign injects: the host's own stall

    def expected(name: str, message: str) -> bool:
        return (crossed and message.startswith("the run was due to end")) or (
            beyond and name == "back_in_control" and "(host_stall" in message
        )

    left = {k: [m for m in v if not expected(k, m)] for k, v in report.violations.items()}
    assert not any(left.values()), {k: v for k, v in left.items() if v}


@faulted_run_settings(12)
@given(before_end=st.floats(0.3, 1.5), pause_s=st.floats(0.3, 3.0))
@example(before_end=0.5, pause_s=3.0)
def test_a_host_back_after_the_end_says_how_long_the_board_was_out(before_end, pause_s):
    """Its exit once said ``lost: board lost at t=… for 0.0 s (failsafe)``: out since the host's deadline
    it missed, to the run's end at least."""
    run = paused_run(DURATION_S - before_end, pause_s)
    paused_at = run.pause.paused_at
    assert paused_at is not None
    if paused_at + pause_s < run.end:
        return  # back before the end: as any pause
    exit_ = run.summary["exit"]
    assert exit_.startswith("lost:") and "host_stall" in exit_, exit_
    outage = run.summary["outages"][-1]
    assert outage["end"] is None and abs(outage["start"] - paused_at) < 1e-6
    assert outage["duration_s"] >= pause_s - 1e-9, (outage, exit_)


@settings(max_examples=60, deadline=None)
@given(pause_s=st.floats(0.3, 12.0), kept=st.integers(1, 40), failsafe_after=st.floats(0.25, 0.3))
def test_a_failsafe_read_from_a_backlog_is_dated_when_the_board_made_it(pause_s, kept, failsafe_after):
    """Through the sans-IO session: a board ARMED, the host stops reading, the board fails safe
    ``failsafe_after`` s into the pause; its backlog (the first ``kept`` frames, ARMED then FAILSAFE) read
    in one go at the pause's end. The StateEvent to FAILSAFE is dated when the board's frame said it,
    within the link's jitter — not at the read."""
    s, _ = connected()
    board = Framer()
    period = 0.02
    t, read_end = 0.0, 0.01
    while t < 3.0:  # prompt reads: ARMED
        t += period
        s.feed(board.encode(_tel(t, BoardState.ARMED))[1], t + 0.001, read_end)
        read_end = t + 0.001
    s.take_events()
    resume = read_end + pause_s
    made = [read_end + (i + 1) * period for i in range(int(pause_s / period))]
    made = [m for m in made if m > read_end + failsafe_after][: max(kept, 1)]
    if not made:
        return
    first_fs = made[0]
    frames = [_tel(m, BoardState.FAILSAFE) for m in made]
    s.feed(b"".join(board.encode(f)[1] for f in frames), resume, read_end)
    states = [e for e in s.take_events() if isinstance(e, StateEvent)]
    assert [e.new for e in states] == [BoardState.FAILSAFE]
    assert abs(states[0].t - first_fs) <= 0.002 + 1e-9, (states[0].t, first_fs, resume)


def _tel(t: float, state: BoardState):  # type: ignore[no-untyped-def]
    """The board's telemetry made at host time ``t`` (its uptime runs with the host's clock from 5 s)."""
    from dataclasses import replace

    return replace(telemetry(5_000 + round(t * 1000)), state=state)
