"""Beside the tested one-at-a-time download: a second calibration download started while the first one's
fragments are arriving (two callers of one session; a board that serves downloads side by side, or one
that refuses the second ``BUSY``). The session's downloads shared one reassembler, and starting a download
wiped it: the first download's fragments already acknowledged were gone, the board never sends them
again, and that download never completed. The host's session is driven through its bytes-in/bytes-out
interface; the board's side is played with the protocol's own codec and fragmenter."""

from __future__ import annotations

import hypothesis.strategies as st
from hypothesis import given, settings

from hil.link.board.session import Phase, Session
from protocol.calibration import default_unit_calibration, fragment
from protocol.frame import Deframer, Frame, Framer
from protocol.messages import (
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    Ack,
    BoardState,
    CalibrationRequest,
    HelloReply,
    Nack,
    NackReason,
)


class PlayedBoard:
    """The board's end: its own frame numbering, and what the host wrote, decoded."""

    def __init__(self) -> None:
        self.framer = Framer()
        self.deframer = Deframer()

    def heard(self, data: bytes) -> list[Frame]:
        return [e for e in self.deframer.feed(data) if isinstance(e, Frame)]

    def says(self, message: object) -> bytes:
        return self.framer.encode(message)[1]


@settings(max_examples=60, deadline=None)
@given(
    before=st.integers(0, 2),  # fragments of the first download fed before the second one starts
    second_refused=st.booleans(),  # the project's boards refuse it BUSY; another may serve both
    interleave=st.booleans(),
)
def test_a_download_started_while_another_runs_leaves_the_first_intact(
    before: int, second_refused: bool, interleave: bool
) -> None:
    session, board, now = Session(), PlayedBoard(), 0.0
    board.heard(session.link_up(now))
    reply = HelloReply(PROTOCOL_VERSION, SCHEMA_HASH, state=BoardState.DISARMED, n_units=4, boot_id=0x1234)
    board.heard(session.feed(board.says(reply), now))
    assert session.phase is Phase.READY
    stored = default_unit_calibration().to_bytes()
    sets = {0: stored, 1: bytes(reversed(stored))}  # the second's bytes only travel: never parsed

    def request(unit: int) -> tuple[object, CalibrationRequest, int]:
        download, data = session.start_download(unit, now)
        (frame,) = board.heard(data)
        return download, frame.message, frame.seq

    first, first_request, seq = request(0)
    session.feed(board.says(Ack(msg_id=CalibrationRequest.MSG_ID, seq=seq)), now)
    first_fragments = fragment(0, first_request.transfer_id, sets[0])
    assert len(first_fragments) == 3
    for part in first_fragments[:before]:
        session.feed(board.says(part), now)
    second, second_request, seq = request(1)
    if second_refused:
        answer: Ack | Nack = Nack(msg_id=CalibrationRequest.MSG_ID, seq=seq, reason=NackReason.BUSY)
        second_fragments = []
    else:
        answer = Ack(msg_id=CalibrationRequest.MSG_ID, seq=seq)
        second_fragments = fragment(1, second_request.transfer_id, sets[1])
    session.feed(board.says(answer), now)
    rest = first_fragments[before:]
    order = (
        [p for pair in zip(rest, second_fragments, strict=False) for p in pair]
        + rest[len(second_fragments) :]
        + second_fragments[len(rest) :]
        if interleave
        else rest + second_fragments
    )
    for part in order:
        now += 0.001
        for frame in board.heard(session.feed(board.says(part), now)):
            assert isinstance(frame.message, Ack)  # every fragment taken
    assert first.done and first.result().to_bytes() == sets[0]
    assert second.done
    if second_refused:
        assert second.error is not None and "BUSY" in str(second.error)
    else:
        assert second.data == sets[1]
