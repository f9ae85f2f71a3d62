"""A board that acknowledges the operator's Disarm and does not carry it out, at drawn moments of a short
lockstep run (the built-in emulator, its Disarm handler made to answer and do nothing: a firmware that
ignores it, or an Arm of an older try that reached it after the Disarm).

Before: the board said ARMED in every heartbeat and telemetry frame from the Disarm to the run's end, its
rotors spinning, while the run was suspended and showed the board live — no fault, no warning, no second
Disarm; the summary's ``faults`` empty. An abort ended with ``board disarmed, telemetry says ARMED`` and
closed the port on the armed board without another Disarm.

Now (:meth:`hil.runtime.watch.BoardWatch.hold_disarmed`): telemetry made
:data:`~hil.runtime.watch.STATE_CONFIRM_S` after the Disarm was settled that still says ARMED is an
``armed`` fault (an outage, ``unasked_arm`` in ``events.jsonl``, a warning) and the Disarm is sent again
until the board is out of ARMED; a board that never obeys is lost within the run's bound, and an abort
says what the telemetry showed and disarms again on its way out.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import pytest
from hypothesis import given
from hypothesis import strategies as st

from firmware_sim.board import commands
from hil.runtime import RunOptions, run
from hil.runtime.observer import Observers
from hil.runtime.operator import OperatorCommand, ScheduledOperator
from hil.runtime.record import RunRecorder
from hil.runtime.watch import STATE_CONFIRM_S
from protocol.messages import BoardState, Disarm
from tests.fault_support import faulted_run_settings, short_scenario

RECOVER_WITHIN_S = 2.0  # the run's bound for an outage: a board that never disarms is lost this soon


@contextmanager
def disarms_ignored(count: int) -> Iterator[list[int]]:
    """The emulator's boards answer their first ``count`` Disarms (an Ack) and stay as they were; the
    list yields how many each board ignored."""
    ignored = [0]
    execute = commands.EXECUTE[Disarm]
    assert execute is not None

    def ignore_some(handler: commands.CommandHandler, msg: Disarm, t: int) -> None:
        if ignored[0] < count:
            ignored[0] += 1
            return None  # accepted, not carried out
        return execute(handler, msg, t)

    commands.EXECUTE[Disarm] = ignore_some
    try:
        yield ignored
    finally:
        commands.EXECUTE[Disarm] = execute


def run_with(command: str, at: float, ignored: int) -> tuple[RunRecorder, list[int]]:
    """The short scenario with the operator's ``command`` at ``at`` (s), the board ignoring its first
    ``ignored`` Disarms."""
    sc = short_scenario()
    recorder = RunRecorder(sc.n_units)
    operator = ScheduledOperator([(at, OperatorCommand(1, command, origin="campaign"))])
    with disarms_ignored(ignored) as count:
        opts = RunOptions(
            out_root=None,
            observer=Observers(recorder, operator),
            rows_to_observer=True,
            recover_within_s=RECOVER_WITHIN_S,
        )
        run(sc, opts)
    return recorder, count


def kinds(recorder: RunRecorder) -> list[str]:
    return [e["kind"] for e in recorder.events]


PHASES = st.one_of(st.floats(1.0, 9.0), st.sampled_from([1.0, 2.121, 3.681, 6.0]))
"""The Disarm's moment: the warm-up's still window, the spin-up, the slew's start, the slew, the hold."""


@faulted_run_settings(6)
@given(at=PHASES)
def test_a_board_that_never_disarms_is_a_fault_disarmed_again_and_the_run_lost_not_completed(at):
    recorder, ignored = run_with("disarm", round(at, 3), ignored=10_000)
    s = recorder.summary
    assert s["exit"].startswith("lost") and "armed" in s["exit"], s["exit"]
    armed = [f for f in s["faults"] if f["kind"] == "armed"]
    assert len(armed) == 1 and at + STATE_CONFIRM_S <= armed[0]["t"] <= at + STATE_CONFIRM_S + 0.2
    assert kinds(recorder).count("unasked_arm") == 1
    resent = kinds(recorder).count("disarm_resent")
    assert resent >= 2 and ignored[0] >= resent  # the board got them all, and ignored them
    rows = recorder.rows()
    after = [state for t, state in zip(rows["t"], rows["board_state"], strict=True) if t > armed[0]["t"]]
    assert set(after) == {BoardState.ARMED}  # honestly shown as it is


@faulted_run_settings(6)
@given(at=PHASES)
def test_a_disarm_carried_out_when_sent_again_ends_the_episode_and_the_run_stays_suspended(at):
    recorder, ignored = run_with("disarm", round(at, 3), ignored=1)
    s = recorder.summary
    assert ignored == [1]
    assert not s["exit"].startswith(("completed", "lost")), s["exit"]  # disarmed by its operator
    assert [f["kind"] for f in s["faults"]] == ["armed"]
    assert kinds(recorder).count("unasked_arm") == 1 and kinds(recorder).count("disarm_resent") == 1
    assert [o["causes"] for o in s["outages"]] == [["armed"]] and s["outages"][0]["end"] is not None
    rows = recorder.rows()
    assert rows["board_state"][-1] == BoardState.DISARMED


def test_a_disarm_the_board_carries_out_is_no_fault():
    recorder, ignored = run_with("disarm", 6.0, ignored=0)
    assert ignored == [0] and recorder.summary["faults"] == []
    assert "unasked_arm" not in kinds(recorder) and "disarm_resent" not in kinds(recorder)


@pytest.mark.parametrize("at", [2.121, 6.0])
def test_an_abort_the_board_does_not_carry_out_says_so_and_disarms_again_on_the_way_out(at):
    recorder, ignored = run_with("abort", at, ignored=10_000)
    exit_ = recorder.summary["exit"]
    assert exit_.startswith("aborted") and "still says ARMED" in exit_ and "board disarmed" not in exit_
    way_out = [e for e in recorder.events if e["kind"] in ("disarmed", "disarm_failed")]
    assert len(way_out) == 1 and way_out[0]["reason"].startswith("aborted")
    assert ignored[0] == 2  # the abort's Disarm and the one on the way out
