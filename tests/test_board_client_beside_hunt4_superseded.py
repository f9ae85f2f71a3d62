"""Beside the tested supersession (a newer Arm stops a pending Disarm's retries): what the host then says of
the superseded command.

A Disarm sent into a slow link, then an Arm: the Disarm is superseded at once — FAILED, "superseded by a
newer Arm" — though a try of it may be on its way, or carried out with its Ack still coming. The board
carries it out, Acks it, then carries out the Arm; the host counted that Ack as a late answer and nothing
more, and the run's record said the Disarm failed. Now the superseded command says that whether it was
carried out is not known, and its late answer, when it comes, is kept on it (``carried_out``,
``late_reply``, its failure saying what the board did) and told as a :class:`CommandEvent`; the board's
state is left to the newer command.

The host's session is driven through its bytes-in/bytes-out interface with injected time; the board is
played with the protocol's own codec.
"""

from __future__ import annotations

import hypothesis.strategies as st
from hypothesis import given, settings

from hil.link.board import CommandEvent, Phase, Session
from protocol.frame import Deframer, Frame, Framer
from protocol.messages import (
    SCHEMA_HASH,
    Ack,
    Arm,
    BoardState,
    Disarm,
    HelloReply,
    Nack,
    NackReason,
)
from protocol.reliable import CommandState


def frames(data: bytes, deframer: Deframer) -> list[Frame]:
    return [e for e in deframer.feed(data) if isinstance(e, Frame)]


@settings(max_examples=80, deadline=None)
@given(
    retries_before_arm=st.integers(0, 3),  # the Disarm's retries sent before the operator's Arm
    outcome=st.sampled_from(["acked", "nacked", "lost"]),  # what became of the Disarm on the board
    answered_try=st.integers(0, 3),  # which of the Disarm's tries the board answers
    arm_answered=st.booleans(),
)
def test_a_superseded_command_says_what_the_board_did_once_its_answer_comes(
    retries_before_arm: int, outcome: str, answered_try: int, arm_answered: bool
) -> None:
    s, board, heard = Session(), Framer(), Deframer()
    frames(s.link_up(0.0), heard)
    reply = HelloReply(
        schema_hash=SCHEMA_HASH, state=BoardState.ARMED, n_units=2, frame_rate_hz=50, boot_id=9
    )
    s.feed(board.encode(reply)[1], 0.01)
    assert s.phase is Phase.READY
    s.take_events()

    now = 0.02
    disarm, data = s.command(Disarm(), now)
    disarm_tries = [f for f in frames(data, heard) if isinstance(f.message, Disarm)]
    for _ in range(retries_before_arm):
        now += s.config.commands.timeout(1) + 0.001
        disarm_tries += [f for f in frames(s.poll(now), heard) if isinstance(f.message, Disarm)]
    now += 0.001
    arm, data = s.command(Arm(), now)
    (arm_frame,) = [f for f in frames(data, heard) if isinstance(f.message, Arm)]

    # superseded at once: failed, never said not carried out
    assert disarm.state is CommandState.FAILED and "superseded by a newer Arm" in disarm.failure
    assert "not known" in disarm.failure and disarm.carried_out is None
    assert s.commands.stats.superseded == 1

    # the board carries out (or refuses) the Disarm, then the Arm, answering in that order
    answered = disarm_tries[min(answered_try, len(disarm_tries) - 1)]
    now += 0.005
    if outcome == "acked":
        s.feed(board.encode(Ack(msg_id=answered.msg_id, seq=answered.seq))[1], now)
    elif outcome == "nacked":
        nack = Nack(msg_id=answered.msg_id, seq=answered.seq, reason=NackReason.BAD_STATE)
        s.feed(board.encode(nack)[1], now)
    if arm_answered:
        now += 0.001
        s.feed(board.encode(Ack(msg_id=arm_frame.msg_id, seq=arm_frame.seq))[1], now)

    told = [e for e in s.take_events() if isinstance(e, CommandEvent)]
    assert disarm.state is CommandState.FAILED  # settled once: it stays so
    if outcome == "lost":
        assert disarm.carried_out is None and "not known" in disarm.failure and told == []
    else:
        carried = outcome == "acked"
        assert disarm.carried_out is carried
        assert (
            "carried it out" if carried else "refused it (its Nack came late: BAD_STATE)"
        ) in disarm.failure
        assert isinstance(disarm.late_reply, Ack if carried else Nack)
        assert len(told) == 1 and told[0].ok is carried and "Disarm" in told[0].command
        assert "superseded by Arm" in told[0].command and told[0].detail == disarm.failure
    assert s.commands.stats.late_answers == (0 if outcome == "lost" else 1)
    if arm_answered:  # the late Disarm answer never undoes what the newer Arm made known
        assert arm.ok and arm.carried_out is True and s.state is BoardState.ARMED and s.armed
