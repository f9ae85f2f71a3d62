"""Far sides that answer, but wrongly: one HelloReply repeated to every frame, a HelloReply of another
protocol version in the middle of a session, a flood of Nacks naming nothing the host sent, every command
answered twice — through the sans-IO session with injected time.

Before the fixes: the same HelloReply frame repeated (a far side stuck on its greeting) kept the link
looking alive for ever — ``last_heard`` moving, no silence reported — while no command was answered; the
unasked-for HelloReplies (another protocol's among them) and the Nacks naming no command were counted in
the reliable senders' statistics and nowhere said: no log line told the operator what the far side did.
"""

from __future__ import annotations

import logging

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_board_link_beside_echo import connected, hello_reply, telemetry

from hil.link.board import Phase, Session, SilenceEvent
from hil.link.board.session import DROP_WARN_EVERY_S
from protocol.frame import Framer
from protocol.messages import PROTOCOL_VERSION, Ack, Arm, HelloReply, Nack, NackReason

LOGGER = "hil.link.board.session"


class Recorder(logging.Handler):
    """The messages logged through it (caplog is function-scoped: not for a Hypothesis test's examples)."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(record.getMessage())


def drops(caplog: pytest.LogCaptureFixture, text: str) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == LOGGER and text in r.getMessage()]


def test_one_hello_reply_repeated_to_every_frame_is_silence_not_a_live_board(caplog):
    """The far side answers each of the host's frames with the very HelloReply frame that answered its
    Hello: the session stays with the board it had, its Arm goes unanswered (a typed failure), the repeats
    are counted and logged at the drop warnings' rate, and the silence is reported: no frame of the
    board's since its greeting."""
    s = Session()
    greeting = Framer().encode(hello_reply())[1]
    s.link_up(0.0)
    s.feed(greeting, 0.01)
    arm, out = s.command(Arm(), 0.02)
    t = 0.02
    with caplog.at_level(logging.WARNING, LOGGER):
        while t < 3.0:
            s.feed(greeting * max(out.count(0), 1), t + 0.001)  # one greeting per frame the host wrote
            t = round(t + 0.01, 6)
            out = s.poll(t)
    assert arm.done and not arm.ok and "no answer after" in arm.failure
    assert s.last_heard == 0.01
    silences = [e for e in s.take_events() if isinstance(e, SilenceEvent)]
    assert [e.ended for e in silences] == [False] and silences[0].since == 0.01
    said = drops(caplog, "a HelloReply no Hello was waiting for, from the session's board")
    assert 2 <= len(said) <= 3.0 / DROP_WARN_EVERY_S + 1
    assert s.hellos.stats.late_answers > 100 and s.phase is Phase.READY and s.counters.handshakes == 1


def test_a_hello_reply_of_another_protocol_mid_session_is_dropped_and_said(caplog):
    """Unasked for, in the middle of a session: the session keeps its board and its telemetry flowing;
    the reply is counted and logged naming its protocol version."""
    s, board = connected()
    other = HelloReply(protocol_version=PROTOCOL_VERSION + 1, n_units=2, model="OTHER")
    with caplog.at_level(logging.WARNING, LOGGER):
        s.feed(board.encode(telemetry(1_000))[1], 0.1)
        s.feed(board.encode(other)[1], 0.2)
        s.feed(board.encode(telemetry(1_200))[1], 0.3)
    assert s.phase is Phase.READY and s.info is not None and s.info.identity.model == "SCRIPTED"
    assert s.telemetry is not None and s.telemetry.time_ms == 1_200
    assert s.hellos.stats.late_answers == 1
    (said,) = drops(caplog, "a HelloReply no Hello was waiting for")
    assert f"from a board of protocol {PROTOCOL_VERSION + 1}" in said and "OTHER" in said


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(flood=st.integers(1, 3_000), span_s=st.floats(0.0, 5.0))
def test_a_flood_of_nacks_naming_nothing_is_counted_and_logged_at_a_bounded_rate(flood, span_s):
    """Nacks naming no command the host sent, ``flood`` of them over ``span_s``: each counted, at most one
    warning per DROP_WARN_EVERY_S (the next one saying how many since); the Arm in flight among them is
    settled by its own Ack, once."""
    s, board = connected()
    arm, _ = s.command(Arm(), 0.02)
    handler = Recorder()
    records = handler.messages
    logger = logging.getLogger(LOGGER)
    logger.addHandler(handler)
    try:
        for k in range(flood):
            t = 0.03 + span_s * k / flood
            nack = Nack(msg_id=0x11, seq=(arm.seq + 1 + k) % 256, reason=NackReason.BAD_STATE)
            s.feed(board.encode(nack)[1], t)
            if k == flood // 2:
                s.feed(board.encode(Ack(msg_id=arm.msg_id, seq=arm.seq))[1], t)
    finally:
        logger.removeHandler(handler)
    assert arm.ok and s.commands.stats.acked == 1
    assert s.commands.stats.unmatched_answers == flood
    said = [m for m in records if "naming no command the host sent" in m]
    assert 1 <= len(said) <= span_s / DROP_WARN_EVERY_S + 1


def test_every_command_answered_twice_settles_once_and_counts_the_second_quietly(caplog):
    """A board answering each command twice: each command settles once, the second answer is a late
    one (counted), and nothing is logged for it — a lossy link's retries make such answers every day."""
    s, board = connected()
    with caplog.at_level(logging.WARNING, LOGGER):
        for k in range(5):
            cmd, _ = s.command(Arm(), 0.1 * k + 0.02)
            ack = board.encode(Ack(msg_id=cmd.msg_id, seq=cmd.seq))[1]
            s.feed(ack, 0.1 * k + 0.03)
            s.feed(board.encode(Ack(msg_id=cmd.msg_id, seq=cmd.seq))[1], 0.1 * k + 0.031)
            assert cmd.ok
    stats = s.commands.stats
    assert (stats.acked, stats.late_answers, stats.unmatched_answers) == (5, 5, 0)
    assert not drops(caplog, "dropped")


@pytest.mark.parametrize("tries", [2, 3])
def test_a_slow_boards_answers_to_the_earlier_hello_tries_are_late_not_warned(caplog, tries):
    """A board that answers only after the host has sent its Hello ``tries`` times (a USB accessory that
    opens after the host's first Hellos) answers every try: the first answer settles the handshake, the
    others are counted late, quietly — every such run logged a warning for its own handshake. One answer
    more than the tries is no such answer: said, as before."""
    s = Session()
    board = Framer()
    s.link_up(0.0)
    t = 0.0
    while s.hellos.pending[0].tries < tries:
        t = round(t + 0.01, 6)
        s.poll(t)
    with caplog.at_level(logging.WARNING, LOGGER):
        for k in range(tries):  # one answer per try, the first of them settling the Hello
            s.feed(board.encode(hello_reply())[1], t + 0.001 * (k + 1))
        assert s.phase is Phase.READY and s.counters.handshakes == 1
        assert s.hellos.stats.late_answers == tries - 1
        assert not drops(caplog, "a HelloReply no Hello was waiting for")
        s.feed(board.encode(hello_reply())[1], t + 0.1)
    (said,) = drops(caplog, "a HelloReply no Hello was waiting for")
    assert "from the session's board" in said


IDENTITY = ("manufacturer", "model", "description", "version", "uri", "serial")
ASCII = st.characters(min_codepoint=1, max_codepoint=126)  # within every identity field's bytes on the wire


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(field=st.sampled_from(IDENTITY), before=st.text(ASCII, max_size=6), after=st.text(ASCII, max_size=6))
def test_a_hello_reply_whose_identity_holds_a_nul_is_a_handshake_error_or_a_drop(field, before, after):
    """An identity string with a NUL inside decodes (the frame's text field takes it) but is no
    accessory's: it raised FieldRangeError out of ``Session.feed`` — at the handshake with the Hello
    settled and the session half made, mid-session with the frames after it in that read unread. Now the
    handshake fails as incompatible, naming the HelloReply's field, and an unasked-for one is dropped with
    the session and its telemetry going on."""
    import dataclasses

    bad = dataclasses.replace(hello_reply(), **{field: f"{before}\x00{after}"})
    s = Session()
    s.link_up(0.0)
    s.poll(0.0)
    s.feed(Framer().encode(bad)[1], 0.01)
    assert s.phase is Phase.INCOMPATIBLE and s.info is None
    assert f"AccessoryIdentity.{field} = " in str(s.failure) and "HelloReply" in str(s.failure)

    s, board = connected()
    handler = Recorder()
    logger = logging.getLogger(LOGGER)
    logger.addHandler(handler)
    try:
        s.feed(board.encode(bad)[1] + board.encode(telemetry(1_000))[1], 0.1)  # one read: both frames
    finally:
        logger.removeHandler(handler)
    assert s.phase is Phase.READY and s.info is not None and s.info.identity.model == "SCRIPTED"
    assert s.telemetry is not None and s.telemetry.time_ms == 1_000
    assert any("whose identity no accessory has" in m for m in handler.messages)
