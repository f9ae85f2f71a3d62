"""A board that acknowledges the host's Arm and stays DISARMED, at drawn moments of a short lockstep run (the
built-in emulator, its Arm handler made to answer and do nothing: a firmware that ignores it, an Arm refused
in all but its answer): from the run's first Arm, or from the operator's Arm after a Disarm in any phase.

Before: the host took the acknowledgement for ARMED. The first such Arm was caught by the state change it
seemed to make (ARMED → DISARMED with no Disarm meant: ``unasked_disarm``), but the re-arm after it, also
acknowledged and ignored, was not: the run sat blind, no second Arm sent, until it was lost — a board that
would have obeyed a third Arm was never given one.

Now (:meth:`hil.runtime.watch.BoardWatch.hold_armed`): live telemetry made
:data:`~hil.runtime.watch.STATE_CONFIRM_S` after the board acknowledged an Arm that still says DISARMED is
a ``disarmed`` fault (``arm_unheeded`` in ``events.jsonl``, once an episode) and the Arm is sent again until
the board is ARMED; a board that never obeys is lost within the run's bound, its rows showing it DISARMED.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from hypothesis import given
from hypothesis import strategies as st

from firmware_sim.board import commands
from hil.runtime import RunOptions, run
from hil.runtime.observer import Observers
from hil.runtime.operator import OperatorCommand, ScheduledOperator
from hil.runtime.record import RunRecorder
from hil.runtime.watch import STATE_CONFIRM_S
from protocol.messages import Arm, BoardState, Disarm
from tests.fault_support import faulted_run_settings, short_scenario

RECOVER_WITHIN_S = 2.0  # the run's bound for an outage: a board that never arms is lost this soon
OPERATOR_ARM_AFTER_S = 0.5  # the operator's Arm, this long after its Disarm


@contextmanager
def arms_ignored(count: int, after_a_disarm: bool) -> Iterator[list[int]]:
    """The emulator's boards answer ``count`` Arms (an Ack) and stay as they were: the first ones, or
    (``after_a_disarm``) the first ones after the board carried out a Disarm; the list yields how many
    were ignored."""
    ignored = [0]
    disarmed = [not after_a_disarm]
    execute_arm, execute_disarm = commands.EXECUTE[Arm], commands.EXECUTE[Disarm]
    assert execute_arm is not None and execute_disarm is not None

    def ignore_some(handler: commands.CommandHandler, msg: Arm, t: int) -> None:
        if disarmed[0] and ignored[0] < count:
            ignored[0] += 1
            return None  # accepted, not carried out
        return execute_arm(handler, msg, t)

    def note_disarm(handler: commands.CommandHandler, msg: Disarm, t: int) -> object:
        disarmed[0] = True
        return execute_disarm(handler, msg, t)

    commands.EXECUTE[Arm], commands.EXECUTE[Disarm] = ignore_some, note_disarm
    try:
        yield ignored
    finally:
        commands.EXECUTE[Arm], commands.EXECUTE[Disarm] = execute_arm, execute_disarm


def run_with(ignored: int, operator_at: float | None) -> tuple[RunRecorder, list[int]]:
    """The short scenario, its board ignoring ``ignored`` Arms: from the start, or (``operator_at``, s)
    from the operator's Disarm then, followed by the operator's Arm."""
    sc = short_scenario()
    recorder = RunRecorder(sc.n_units)
    observer: object = recorder
    if operator_at is not None:
        schedule = [
            (operator_at, OperatorCommand(1, "disarm", origin="campaign")),
            (operator_at + OPERATOR_ARM_AFTER_S, OperatorCommand(2, "arm", origin="campaign")),
        ]
        observer = Observers(recorder, ScheduledOperator(schedule))
    with arms_ignored(ignored, after_a_disarm=operator_at is not None) as count:
        opts = RunOptions(
            out_root=None, observer=observer, rows_to_observer=True, recover_within_s=RECOVER_WITHIN_S
        )
        run(sc, opts)
    return recorder, count


def kinds(recorder: RunRecorder) -> list[str]:
    return [e["kind"] for e in recorder.events]


PHASES = st.one_of(st.none(), st.floats(1.0, 8.0), st.sampled_from([1.0, 2.121, 3.681, 6.0]))
"""The operator's Disarm and Arm (None: the run's own first Arm is the one ignored): the warm-up's still
window, the spin-up, the slew's start, the slew, the hold."""


@faulted_run_settings(6)
@given(at=PHASES, ignored=st.integers(2, 3))
def test_arms_acknowledged_and_not_carried_out_are_sent_again_until_the_board_is_armed(at, ignored):
    at = None if at is None else round(at, 3)
    recorder, count = run_with(ignored, at)
    s = recorder.summary
    assert count == [ignored]
    assert not s["exit"].startswith("lost"), s["exit"]  # re-armed within the bound, not given up on
    unheeded = [e for e in recorder.events if e["kind"] == "arm_unheeded"]
    assert len(unheeded) == 1  # once an episode, however many Arms it took
    assert unheeded[0]["t"] >= unheeded[0]["acked"] + STATE_CONFIRM_S
    details = [f["detail"] for f in s["faults"] if f["kind"] == "disarmed"]
    assert "the board says DISARMED after it acknowledged the Arm" in details
    assert s["outages"] and all(o["end"] is not None for o in s["outages"])
    assert recorder.rows()["board_state"][-1] == BoardState.ARMED


@faulted_run_settings(4)
@given(at=PHASES)
def test_a_board_that_never_arms_is_sent_the_arm_again_and_lost_not_completed(at):
    at = None if at is None else round(at, 3)
    recorder, count = run_with(10_000, at)
    s = recorder.summary
    assert s["exit"].startswith("lost") and "disarmed" in s["exit"], s["exit"]
    sent = kinds(recorder).count("rearm_sent")
    assert sent >= 3 and count[0] >= sent  # the Arm sent again, every one ignored
    assert kinds(recorder).count("arm_unheeded") == 1
    rows = recorder.rows()
    lost_at = next(e["t"] for e in recorder.events if e["kind"] == "lost")
    late = [state for t, state in zip(rows["t"], rows["board_state"], strict=True) if t > lost_at - 1.0]
    assert set(late) == {BoardState.DISARMED}  # honestly shown as it is


def test_an_arm_the_board_carries_out_is_no_fault():
    recorder, count = run_with(0, 3.0)
    assert count == [0]
    assert "arm_unheeded" not in kinds(recorder)
    assert all(f["kind"] != "disarmed" for f in recorder.summary["faults"])
