"""Beside the bulk OUT pipe's tested path: a packet the phone took whose ACK was lost on the way back.

The chip reports a bus error (hrTIMEOUT) for a bulk OUT packet that got no handshake; the phone may well
hold it (its data toggle moved on). The board sent the bytes again on the next pass - but as a fresh packet
peeked from its transmit queue, so if more bytes had been queued meanwhile the retry was longer than the
packet the phone took. The phone, seeing the same toggle, discards the retry as a repeat (USB's rule), and
the board, on its ACK, consumed every byte of it: the ones queued since were lost, silently, mid-frame. Now
the packet without a handshake is sent again exactly (the same bytes, or the same zero-length packet).

The stack on the host through ctypes (``test_firmware_usb_stack.Stack``) against the MAX3421E + phone model,
whose ``lost_ack`` fault drops the handshakes of the next N bulk OUT packets the phone takes and reports a
repeat that is not the packet it took last as a violation in ``last_error``."""

from __future__ import annotations

import hypothesis.strategies as st
import pytest
from hypothesis import HealthCheck, given, settings
from test_firmware_usb_stack import RUNNING, Stack

from protocol.frame import Frame, decode_stream, encode_frame
from protocol.messages import Heartbeat

pytestmark = pytest.mark.firmware

STEPS = st.lists(
    st.tuples(
        st.binary(min_size=0, max_size=200),  # what the board queues for the phone this step
        st.integers(0, 3),  # handshakes lost from now on
        st.integers(0, 3),  # NAKs before each data transaction (the phone's buffer busy)
        st.integers(1, 4),  # passes run
    ),
    min_size=1,
    max_size=25,
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(steps=STEPS)
def test_bytes_to_the_phone_arrive_exactly_whatever_handshakes_are_lost(steps) -> None:
    s = Stack()
    try:
        assert s.run_until(RUNNING) > 0
        sent, got = bytearray(), bytearray()
        for data, lost, naks, passes in steps:
            if data:
                s.board_write(data)
                sent += data
            s.fault("lost_ack", lost)
            s.fault("nak", naks)
            got += s.pump(passes)[1]
            assert s.last_error() == "", s.last_error()
        s.fault("lost_ack", 0)
        s.fault("nak", 0)
        got += s.pump(400)[1]
        assert s.lib.usbc_board_tx_pending() == 0
        assert bytes(got) == bytes(sent)  # nothing lost, nothing doubled
        assert s.state == RUNNING
        assert s.last_error() == ""
    finally:
        s.close()


def test_frames_queued_while_a_packet_waits_for_its_retry_all_decode() -> None:
    """The board's own traffic: a frame goes out, its packet's ACK is lost, the next frames are queued
    before the retry - every frame reaches the phone's app whole, in order."""
    s = Stack()
    try:
        assert s.run_until(RUNNING) > 0
        frames = [encode_frame(Heartbeat(time_ms=i, state=1), i) for i in range(12)]
        s.board_write(frames[0])
        s.fault("lost_ack", 1)
        phone = s.pump(1)[1]
        for frame in frames[1:]:
            s.board_write(frame)
        phone += s.pump(50)[1]
        events = decode_stream(phone)
        assert [e.message for e in events if isinstance(e, Frame)] == [
            Heartbeat(time_ms=i, state=1) for i in range(12)
        ]
        assert all(isinstance(e, Frame) for e in events), events  # no frame cut or corrupted
        assert s.last_error() == ""
    finally:
        s.close()
