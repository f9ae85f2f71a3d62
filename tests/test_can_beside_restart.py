"""A sender restarted beside the CAN link's path: its transfer ids and sequence numbers begin again, so its
first frame can equal, byte for byte and under the same transfer id, the last frame its predecessor sent
on that arbitration id — a host killed during its handshake and started again sends the very same
``Hello``. Taken for CAN's double reception, that frame was dropped as a duplicate: the new host's
handshake waited for a retry, and a frame sent once was lost. A repeat follows its original at once; a
restarted sender's frame comes later (``REPEAT_WINDOW_S``): that one is delivered."""

from __future__ import annotations

import time

import hypothesis.strategies as st
from can_support import read_until, virtual_url
from hypothesis import given, settings

from firmware_sim.board import Board
from firmware_sim.board.config import BoardConfig
from firmware_sim.servers.can_server import CanServer
from hil.link.transports.can_bus import CanTransport
from hil.timing.clock import WallClock
from protocol.can import REPEAT_WINDOW_S, CanReassembler, CanSegmenter, Direction
from protocol.frame import Deframer, Frame, Framer
from protocol.messages import ActuatorSetpoint, Heartbeat, Hello, HelloReply, UnitSetpoint

NODE = 6

_FIRST = st.sampled_from(
    [Hello(), Heartbeat(time_ms=0), ActuatorSetpoint(units=(UnitSetpoint(0.0, 0.0),) * 4)]
)


@settings(max_examples=80, deadline=None)
@given(
    first=_FIRST,
    fd=st.booleans(),
    sent_before=st.integers(1, 6),
    gap=st.floats(REPEAT_WINDOW_S * 1.01, 30.0),
    repeat_after=st.floats(0.0, REPEAT_WINDOW_S / 2),
    t0=st.floats(0.0, 1e6),
)
def test_a_restarted_sender_s_first_frame_is_delivered_and_a_prompt_repeat_is_not(
    first, fd, sent_before, gap, repeat_after, t0
):
    """Sans-IO, on drawn receive times: a sender says ``first`` and ``sent_before - 1`` others on one
    arbitration id, dies ``gap`` s later than its last frame (longer than a repeat could take) and its
    restarted self says ``first`` again: that frame is delivered. A repeat of it ``repeat_after`` s later
    (well within the window) is still CAN's double reception: counted, not delivered."""
    rx = CanReassembler(NODE, Direction.TO_BOARD, fd=fd)
    t = t0
    seg, framer = CanSegmenter(NODE, Direction.TO_BOARD, fd), Framer(0)
    delivered = []
    for _ in range(sent_before):
        for f in seg.segment(framer.encode(first)[1]):  # one message again and again, as a stream is
            delivered.append(rx.feed(f.arbitration_id, f.data, fd, at=t))
        t += 0.01
    assert sum(1 for d in delivered if d) == sent_before
    seg, framer = CanSegmenter(NODE, Direction.TO_BOARD, fd), Framer(0)  # restarted: ids and seqs from 0
    again = framer.encode(first)[1]
    t += gap
    segments = seg.segment(again)
    out = b"".join(rx.feed(f.arbitration_id, f.data, fd, at=t) for f in segments)
    assert out == again, (rx.stats, sent_before)
    t += repeat_after
    repeat = b"".join(rx.feed(f.arbitration_id, f.data, fd, at=t) for f in segments)
    assert repeat == b"" and rx.stats.duplicates >= len(segments)
    assert rx.stats.frames == sent_before + 1


def _reply(data: bytes) -> bool:
    return any(isinstance(e, Frame) and isinstance(e.message, HelloReply) for e in Deframer().feed(data))


def test_a_host_restarted_during_its_handshake_is_answered_at_its_first_hello():
    """Real buses: a board served on a virtual bus; a host sends its first ``Hello`` and dies; another
    host (a new process: a new framer, new transfer ids) comes 0.3 s later and sends its first ``Hello``
    — the same bytes. The board answers it, at once, and counts no duplicate."""
    url = virtual_url(node=NODE)
    with CanServer(Board(BoardConfig(n_units=1), WallClock()), url) as server:
        time.sleep(0.3)  # the board is past its boot (bytes during its reset are lost, as on the MCU)
        for attempt in range(2):
            with CanTransport(url) as host:
                host.write(Framer(0).encode(Hello())[1])
                got = b""
                deadline = time.monotonic() + 2.0
                while not _reply(got) and time.monotonic() < deadline:
                    got += read_until(host, 1, tries=5)
                assert _reply(got), (attempt, server.counters())
            time.sleep(3 * REPEAT_WINDOW_S)  # the next host process starts
        assert server.counters()["rx_frames"] == 2 and server.counters()["rx_duplicates"] == 0
        server.check()
