"""Reliable commands in simulated time: ACK, NACK, retries with the same sequence number and the
RETRANSMIT flag, give-up, late and duplicate answers; against a model receiver over a lossy link; and
against the emulated board in lockstep."""

from __future__ import annotations

import hypothesis.strategies as st
import pytest
from hypothesis import given, settings

from firmware_sim.board import Board
from firmware_sim.board.config import BoardConfig
from hil.timing.clock import LockstepClock
from protocol.errors import CommandFailed, ConfigError, FieldRangeError, ProtocolError
from protocol.frame import Deframer, Frame, decode_stream, encode_frame
from protocol.messages import (
    SCHEMA_HASH,
    Ack,
    ActuatorSetpoint,
    Arm,
    BoardState,
    CalibrationRequest,
    ControlMode,
    Disarm,
    Flags,
    Heartbeat,
    Hello,
    HelloReply,
    Log,
    Nack,
    NackReason,
    SetMode,
    UnitSetpoint,
)
from protocol.reliable import (
    AnswerCache,
    CommandState,
    ReliableSender,
    RetryPolicy,
    answer_for,
    expects_answer,
)


def _frame(message, seq=0, flags=0) -> Frame:
    [frame] = decode_stream(encode_frame(message, seq, flags))
    return frame


def _ack(cmd) -> Frame:
    return _frame(Ack(msg_id=cmd.msg_id, seq=cmd.seq))


def _sent(data: bytes) -> list[Frame]:
    return decode_stream(data)


# =========================================================================== answers
def test_ack_settles_the_command_and_tells_the_callback_once():
    settled = []
    sender = ReliableSender(on_settled=settled.append)
    cmd, data = sender.send(Arm(), now=1.0)
    [frame] = _sent(data)
    assert (frame.message, frame.seq, frame.flags) == (Arm(), cmd.seq, Flags.ACK_REQUESTED)
    assert cmd.state is CommandState.PENDING and not cmd.done
    assert sender.on_frame(_ack(cmd), now=1.004) is cmd
    assert cmd.state is CommandState.ACKED and cmd.ok
    assert cmd.latency == pytest.approx(0.004)
    assert cmd.result() == Ack(msg_id=Arm.MSG_ID, seq=cmd.seq)
    assert settled == [cmd]
    assert sender.pending == [] and sender.next_deadline() is None
    assert sender.poll(now=10.0) == b""  # nothing left to retry


def test_nack_settles_with_its_reason_and_result_raises():
    sender = ReliableSender()
    cmd, _ = sender.send(SetMode(mode=ControlMode.RAW_PULSES), now=0.0)
    sender.on_frame(_frame(Nack(msg_id=SetMode.MSG_ID, seq=cmd.seq, reason=NackReason.BAD_STATE)), now=0.01)
    assert cmd.state is CommandState.NACKED and cmd.reason is NackReason.BAD_STATE
    with pytest.raises(CommandFailed, match="BAD_STATE"):
        cmd.result()
    assert sender.stats.nacked == 1


def test_pending_result_is_an_error_not_a_value():
    cmd, _ = ReliableSender().send(Arm(), now=0.0)
    with pytest.raises(ProtocolError, match="pending"):
        cmd.result()


# =========================================================================== retries and give-up
def test_retry_resends_the_same_sequence_number_with_retransmit():
    sender = ReliableSender(policy=RetryPolicy(timeout_s=0.1, max_tries=5))
    cmd, first = sender.send(Disarm(), now=0.0)
    assert sender.next_deadline() == pytest.approx(0.1)
    assert sender.poll(0.0999) == b""
    [retry] = _sent(sender.poll(0.1))
    [original] = _sent(first)
    assert retry.message == original.message
    assert retry.seq == original.seq == cmd.seq
    assert retry.flags == Flags.ACK_REQUESTED | Flags.RETRANSMIT
    assert cmd.tries == 2 and cmd.last_sent_at == 0.1
    assert sender.stats.retransmits == 1


def test_gives_up_after_max_tries_and_one_more_timeout():
    settled = []
    # Binary-exact times (1/8 s timeouts, 1/128 s steps) so the deadline comparisons are exact.
    sender = ReliableSender(policy=RetryPolicy(timeout_s=0.125, max_tries=3), on_settled=settled.append)
    cmd, _ = sender.send(Arm(), now=0.0)
    sends = 1
    t = 0.0
    while t < 1.0 and not cmd.done:
        t += 1 / 128
        sends += len(_sent(sender.poll(t)))
    assert sends == 3
    assert cmd.state is CommandState.FAILED and cmd.settled_at == 0.375
    assert "no answer after 3 tries" in cmd.failure
    with pytest.raises(CommandFailed, match="no answer"):
        cmd.result()
    assert settled == [cmd] and sender.stats.failed == 1 and sender.pending == []


def test_backoff_and_cap_set_each_try_timeout():
    policy = RetryPolicy(timeout_s=0.1, max_tries=6, backoff=2.0, max_timeout_s=0.3)
    assert [policy.timeout(k) for k in range(1, 5)] == pytest.approx([0.1, 0.2, 0.3, 0.3])
    sender = ReliableSender(policy=policy)
    sender.send(Arm(), now=0.0)
    deadlines = []
    for _ in range(4):
        deadline = sender.next_deadline()
        deadlines.append(deadline)
        sender.poll(deadline)
    assert deadlines == pytest.approx([0.1, 0.3, 0.6, 0.9])


def test_a_late_poll_waits_a_full_timeout_after_the_retry_it_sends():
    sender = ReliableSender(policy=RetryPolicy(timeout_s=0.1))
    cmd, _ = sender.send(Arm(), now=0.0)
    assert len(_sent(sender.poll(0.35))) == 1  # one retry, not three catch-up copies
    assert sender.next_deadline() == pytest.approx(0.45)
    assert cmd.tries == 2


# =========================================================================== late, duplicate, stray answers
def test_late_and_duplicate_answers_are_counted_not_applied():
    sender = ReliableSender()
    cmd, _ = sender.send(Arm(), now=0.0)
    sender.poll(0.1)  # a retry: the board will answer both tries
    sender.on_frame(_ack(cmd), now=0.11)
    assert sender.on_frame(_ack(cmd), now=0.12) is None  # the answer to the retry, arriving late
    late_nack = _frame(Nack(msg_id=Arm.MSG_ID, seq=cmd.seq, reason=NackReason.POWER))
    assert sender.on_frame(late_nack, now=0.13) is None
    assert cmd.state is CommandState.ACKED
    assert sender.on_frame(_frame(Ack(msg_id=0x7E, seq=3)), now=0.14) is None
    assert (sender.stats.late_answers, sender.stats.unmatched_answers, sender.stats.acked) == (2, 1, 1)


def test_answers_are_matched_by_message_id_and_sequence_number():
    sender = ReliableSender()
    arm, _ = sender.send(Arm(), now=0.0)
    for _ in range(3):  # setpoints share the framer's sequence numbers
        sender.framer.encode(ActuatorSetpoint(units=(UnitSetpoint(),)))
    mode, _ = sender.send(SetMode(mode=ControlMode.SETPOINT), now=0.0)
    assert mode.seq == arm.seq + 4
    # An Ack naming Arm with SetMode's seq answers nothing.
    assert sender.on_frame(_frame(Ack(msg_id=Arm.MSG_ID, seq=mode.seq)), 0.01) is None
    assert sender.on_frame(_ack(mode), 0.02) is mode
    assert arm.state is CommandState.PENDING and mode.state is CommandState.ACKED
    assert sender.pending == [arm]


def test_frames_that_are_not_answers_pass_through():
    sender = ReliableSender()
    sender.send(Arm(), now=0.0)
    assert sender.on_frame(_frame(Heartbeat(time_ms=5, state=1)), 0.01) is None
    assert sender.stats.unmatched_answers == 0 and len(sender) == 1


def test_hello_is_answered_by_hello_reply():
    sender = ReliableSender(policy=RetryPolicy(timeout_s=0.05))
    cmd, _ = sender.send(Hello(schema_hash=SCHEMA_HASH), now=0.0)
    [retry] = _sent(sender.poll(0.05))
    assert retry.seq == cmd.seq and retry.flags == Flags.RETRANSMIT  # Hello does not request an Ack
    reply = HelloReply(schema_hash=SCHEMA_HASH, state=BoardState.DISARMED)
    assert sender.on_frame(_frame(reply), 0.06) is cmd
    assert cmd.result() == reply
    assert sender.on_frame(_frame(reply), 0.07) is None and sender.stats.late_answers == 1


def test_only_answered_messages_can_be_sent_reliably():
    sender = ReliableSender()
    assert expects_answer(Arm()) and expects_answer(Hello()) and not expects_answer(Heartbeat())
    with pytest.raises(ProtocolError, match="not acknowledged"):
        sender.send(ActuatorSetpoint(units=(UnitSetpoint(),)), now=0.0)
    with pytest.raises(FieldRangeError):
        sender.send(CalibrationRequest(unit=99), now=0.0)
    assert len(sender) == 0 and sender.framer.next_seq == 0  # nothing sent, no number used


def test_a_reused_sequence_number_fails_the_stale_command():
    sender = ReliableSender(policy=RetryPolicy(timeout_s=100.0, max_timeout_s=100.0))
    old, _ = sender.send(Arm(), now=0.0)
    for _ in range(255):
        sender.framer.encode(Heartbeat())
    new, _ = sender.send(Arm(), now=1.0)
    assert new.seq == old.seq
    assert old.state is CommandState.FAILED and "reused" in old.failure
    assert sender.on_frame(_ack(new), 1.01) is new


def test_abandon_fails_everything_pending():
    sender = ReliableSender()
    cmds = [sender.send(m, now=0.0)[0] for m in (Arm(), SetMode(ControlMode.SETPOINT))]
    assert sender.abandon(0.5, "board reset") == cmds
    assert all(c.state is CommandState.FAILED and c.failure == "board reset" for c in cmds)
    assert sender.next_deadline() is None


@pytest.mark.parametrize(
    "kwargs",
    [
        {"timeout_s": 0.0},
        {"timeout_s": float("nan")},
        {"max_tries": 0},
        {"max_tries": 2.5},
        {"backoff": 0.5},
        {"timeout_s": 1.0, "max_timeout_s": 0.5},
        {"timeout_s": "0.1"},
    ],
)
def test_bad_retry_policies_are_config_errors(kwargs):
    with pytest.raises(ConfigError, match="RetryPolicy"):
        RetryPolicy(**kwargs)


# =========================================================================== receiver side
def test_answer_cache_repeats_answers_to_retransmissions_only():
    cache = AnswerCache(entries=2)
    first = _frame(Arm(), seq=7, flags=Flags.ACK_REQUESTED)
    retry = _frame(Arm(), seq=7, flags=Flags.ACK_REQUESTED | Flags.RETRANSMIT)
    assert cache.lookup(retry) is None  # never executed: execute it
    answer = answer_for(first, None)
    cache.remember(first, answer)
    assert cache.lookup(first) is None  # not flagged as a retry: a new command
    assert cache.lookup(retry) == Ack(msg_id=Arm.MSG_ID, seq=7)
    other = _frame(SetMode(mode=ControlMode.RAW_PULSES), seq=7, flags=Flags.ACK_REQUESTED | Flags.RETRANSMIT)
    assert cache.lookup(other) is None  # different command under another id
    for seq in (8, 9):
        frame = _frame(Disarm(), seq=seq, flags=Flags.ACK_REQUESTED)
        cache.remember(frame, answer_for(frame, NackReason.BAD_STATE))
    assert cache.lookup(retry) is None  # evicted (2 entries)
    assert cache.duplicates == 1
    assert answer_for(first, NackReason.POWER) == Nack(msg_id=Arm.MSG_ID, seq=7, reason=NackReason.POWER)
    with pytest.raises(ConfigError):
        AnswerCache(entries=0)


# =========================================================================== lossy link vs. model receiver
@settings(max_examples=60, deadline=None)
@given(
    n_commands=st.integers(1, 6),
    drops=st.lists(st.booleans(), min_size=1, max_size=80),
    max_tries=st.integers(1, 5),
)
def test_over_a_lossy_link_every_command_settles_and_runs_at_most_once(n_commands, drops, max_tries):
    """Host and a model receiver exchange frames; ``drops`` decides, frame by frame in both directions,
    which are lost. Invariants: every command settles; ACKED means executed exactly once; a receiver
    never executes the same command twice; no more than ``max_tries`` sends per command."""
    policy = RetryPolicy(timeout_s=0.01, max_tries=max_tries)
    sender = ReliableSender(policy=policy)
    cache = AnswerCache()
    receiver = Deframer()
    executed: dict[tuple[int, int], int] = {}
    loss = iter(drops * 1000)
    sends: dict[int, int] = {}
    cmds = []

    def deliver(data: bytes, now: float) -> None:
        for frame in decode_stream(data):
            sends[frame.seq] = sends.get(frame.seq, 0) + 1
            if next(loss):
                continue  # host -> receiver lost
            [got] = receiver.feed(encode_frame(frame.message, frame.seq, int(frame.flags)))
            answer = cache.lookup(got)
            if answer is None:
                executed[(got.msg_id, got.seq)] = executed.get((got.msg_id, got.seq), 0) + 1
                answer = answer_for(got, None)
                cache.remember(got, answer)
            if next(loss):
                continue  # receiver -> host lost
            sender.on_frame(_frame(answer), now)

    t = 0.0
    for i in range(n_commands):
        cmd, data = sender.send(Arm() if i % 2 == 0 else Disarm(), t)
        cmds.append(cmd)
        deliver(data, t)
    while sender.pending:
        t = sender.next_deadline()
        deliver(sender.poll(t), t)
    for cmd in cmds:
        assert cmd.done
        assert sends[cmd.seq] <= max_tries
        runs = executed.get(cmd.key, 0)
        assert runs <= 1
        if cmd.ok:
            assert runs == 1
    assert sender.stats.acked + sender.stats.failed == n_commands


# =========================================================================== against the emulated board
def test_against_the_emulated_board_a_lost_ack_is_retried_and_answered_from_its_cache():
    clock = LockstepClock()
    board = Board(BoardConfig(n_units=1), clock)
    sender = ReliableSender(policy=RetryPolicy(timeout_s=0.02, max_tries=5))
    deframer = Deframer()
    drop_next_ack = True
    logs = []

    def run(until: float) -> None:
        """Advance board time to ``until`` in 1 ms steps, delivering board output to the sender."""
        nonlocal drop_next_ack
        while clock.now() < until - 1e-12:
            clock.advance(0.001)
            board.step()
            for event in deframer.feed(board.take_output()):
                if not isinstance(event, Frame):
                    continue
                if isinstance(event.message, Log):
                    logs.append(event.message.text)
                if isinstance(event.message, Ack) and drop_next_ack:
                    drop_next_ack = False  # the link loses the board's first Ack
                    continue
                sender.on_frame(event, clock.now())
            board.feed(sender.poll(clock.now()))

    run(board.config.boot_time_s + 0.01)
    hello, data = sender.send(Hello(schema_hash=SCHEMA_HASH, manufacturer="tests"), clock.now())
    board.feed(data)
    run(clock.now() + 0.01)
    assert hello.ok and hello.reply.state is BoardState.DISARMED
    arm, data = sender.send(Arm(), clock.now())
    board.feed(data)
    run(clock.now() + 0.1)
    assert arm.ok and arm.tries == 2  # the first Ack was lost: answered again after one retry
    assert board.state is BoardState.ARMED
    assert board.link.stats.duplicates == 1  # the board answered the retry from its cache...
    assert sum("-> ARMED" in text for text in logs) == 1  # ...and armed once
    assert sender.stats.late_answers == 0 and sender.stats.retransmits == 1


def test_a_newer_command_setting_the_same_thing_stops_the_older_ones_retries():
    """A Disarm sent into a stalled link, then an Arm: retried after the Arm was carried out, the Disarm
    left the board disarmed though the host's last word was Arm. The older one fails, superseded, and is
    never sent again; commands setting something else are left alone."""
    sender = ReliableSender(policy=RetryPolicy(timeout_s=0.1, backoff=1.0, max_tries=5))
    disarm, _ = sender.send(Disarm(), 0.0)
    mode, _ = sender.send(SetMode(ControlMode.SETPOINT), 0.0)
    arm, _ = sender.send(Arm(), 0.05)
    assert disarm.state is CommandState.FAILED and "superseded by a newer Arm" in disarm.failure
    assert mode.state is CommandState.PENDING and arm.state is CommandState.PENDING
    resent = Deframer().feed(sender.poll(0.2))
    assert sorted(type(f.message).__name__ for f in resent) == ["Arm", "SetMode"]
    assert sender.stats.superseded == 1 and sender.stats.failed == 1
    again, _ = sender.send(SetMode(ControlMode.SETPOINT), 0.3)
    assert mode.state is CommandState.FAILED and again.state is CommandState.PENDING
    assert arm.state is CommandState.PENDING and sender.stats.superseded == 2
