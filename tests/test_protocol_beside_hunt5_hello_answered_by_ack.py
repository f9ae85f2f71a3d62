"""Beside the tested handshake (a Hello answered by the board's HelloReply): an Ack or a Nack naming the
Hello's ``(msg_id, seq)`` — an answer for a frame that requested none, from a confused or foreign far
side — comes in on the link at a drawn moment. ``ReliableSender.on_frame`` took it as the Hello's answer:
the handshake was ACKED with an Ack for its reply (``hello.result()`` an Ack, no identity, state or schema
hash: ``hello.reply.state`` raised ``AttributeError``) or NACKED, and the Hello was never retried; the
board's real HelloReply was then counted as a stray. Only a HelloReply settles a Hello; the Ack/Nack is
counted as unmatched."""

from __future__ import annotations

import hypothesis.strategies as st
from hypothesis import example, given, settings

from firmware_sim.board import Board
from firmware_sim.board.config import BoardConfig
from hil.timing.clock import LockstepClock
from protocol.frame import Deframer, Frame, encode_frame
from protocol.messages import SCHEMA_HASH, Ack, BoardState, Hello, HelloReply, Nack, NackReason
from protocol.reliable import CommandState, ReliableSender, RetryPolicy


@settings(max_examples=40, deadline=None)
@given(
    stray_at_ms=st.integers(0, 60),
    stray_is_nack=st.booleans(),
    copies=st.integers(1, 3),
    board_deaf_ms=st.sampled_from([0, 25, 45]),
)
@example(stray_at_ms=0, stray_is_nack=False, copies=1, board_deaf_ms=0)
@example(stray_at_ms=0, stray_is_nack=True, copies=1, board_deaf_ms=25)
def test_only_a_hello_reply_settles_a_hello(stray_at_ms, stray_is_nack, copies, board_deaf_ms):
    clock = LockstepClock()
    board = Board(BoardConfig(n_units=1), clock)
    sender = ReliableSender(policy=RetryPolicy(timeout_s=0.02, max_tries=5))
    deframer = Deframer()

    def step_ms() -> None:
        clock.advance(0.001)
        board.step()
        for event in deframer.feed(board.take_output()):
            if isinstance(event, Frame):
                sender.on_frame(event, clock.now())
        retries = sender.poll(clock.now())
        if clock.now() - sent_at >= board_deaf_ms / 1000:  # deaf for a while: later tries reach it
            board.feed(retries)

    sent_at = 0.0
    while clock.now() < board.config.boot_time_s + 0.01:
        step_ms()
    hello, data = sender.send(Hello(schema_hash=SCHEMA_HASH, manufacturer="tests"), clock.now())
    sent_at = clock.now()
    if board_deaf_ms == 0:
        board.feed(data)
    for ms in range(150):
        if ms == stray_at_ms:  # before, with or after the board's answer
            stray = (
                Nack(msg_id=Hello.MSG_ID, seq=hello.seq, reason=NackReason.BAD_STATE)
                if stray_is_nack
                else Ack(msg_id=Hello.MSG_ID, seq=hello.seq)
            )
            for event in deframer.feed(encode_frame(stray, 0, 0) * copies):
                assert isinstance(event, Frame)
                sender.on_frame(event, clock.now())
        step_ms()
    assert hello.state is CommandState.ACKED, hello
    reply = hello.result()
    assert isinstance(reply, HelloReply) and reply.state is BoardState.DISARMED
    assert reply.schema_hash == SCHEMA_HASH
    assert sender.stats.unmatched_answers == copies
    assert sender.stats.acked == 1 and sender.stats.nacked == 0 and sender.stats.failed == 0
